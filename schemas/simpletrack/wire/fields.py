"""A small declarative validator for msgpack maps, without pydantic (the light client install
has none). It applies the rules of the pydantic models in ``simpletrack.wire.models``
(``strict=True, extra="forbid"``) and reports the error pydantic would list first: the same
reason, dotted field and message (``tests/wire/test_validator_agrees.py`` holds it to that).

Fields are checked in declaration order, each: absent -> ``missing_field``; wrong type ->
``wrong_type``; out of range, bad pattern or length -> ``invalid_value``. Then unknown keys,
in the map's order: ``extra_field`` (a non-string key is ``invalid_value``).
"""

from __future__ import annotations

import contextlib
import re
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from enum import StrEnum
from typing import Any, Generic, TypeVar

from simpletrack.wire.reasons import ErrorReason

T = TypeVar("T")
Check = Callable[[Any], Any]  # the value to keep, or raises Invalid


class Invalid(Exception):
    """A value that breaks the contract; ``loc`` is its path from the message root."""

    def __init__(self, reason: ErrorReason, detail: str, loc: tuple[str | int, ...] = ()) -> None:
        super().__init__(detail)
        self.reason, self.detail, self.loc = reason, detail, loc

    @property
    def field(self) -> str | None:
        return ".".join(str(p) for p in self.loc) or None

    def within(self, key: str | int) -> Invalid:
        self.loc = (key, *self.loc)
        return self


def _plural(n: int) -> str:
    return "" if n == 1 else "s"


def integer(lo: int, hi: int) -> Check:
    """An int (not a bool, not a float) in ``[lo, hi]``."""

    def check(v: Any) -> int:
        if type(v) is not int:
            raise Invalid(ErrorReason.WRONG_TYPE, "Input should be a valid integer")
        if v < lo:
            raise Invalid(
                ErrorReason.INVALID_VALUE, f"Input should be greater than or equal to {lo}"
            )
        if v > hi:
            raise Invalid(ErrorReason.INVALID_VALUE, f"Input should be less than or equal to {hi}")
        return v

    return check


def number(v: Any) -> float:
    """A float; an int is accepted and widened (bools are not numbers here)."""
    if type(v) is float:
        return v
    if type(v) is int:
        return float(v)
    raise Invalid(ErrorReason.WRONG_TYPE, "Input should be a valid number")


def boolean(v: Any) -> bool:
    if type(v) is not bool:
        raise Invalid(ErrorReason.WRONG_TYPE, "Input should be a valid boolean")
    return v


def binary(v: Any) -> bytes:
    if type(v) is not bytes:
        raise Invalid(ErrorReason.WRONG_TYPE, "Input should be a valid bytes")
    return v


def string(min_length: int = 0, max_length: int | None = None, pattern: str | None = None) -> Check:
    # fullmatch, not match: a '$' in the pattern would let a trailing newline through.
    regex = None if pattern is None else re.compile(pattern)

    def check(value: Any) -> str:
        v: str = value
        if type(v) is not str:
            if not isinstance(v, str):  # e.g. numpy's str_ from an encoder's caller
                raise Invalid(ErrorReason.WRONG_TYPE, "Input should be a valid string")
            v = str(v)
        if len(v) < min_length:
            raise Invalid(
                ErrorReason.INVALID_VALUE,
                f"String should have at least {min_length} character{_plural(min_length)}",
            )
        if max_length is not None and len(v) > max_length:
            raise Invalid(
                ErrorReason.INVALID_VALUE,
                f"String should have at most {max_length} character{_plural(max_length)}",
            )
        if regex is not None and regex.fullmatch(v) is None:
            raise Invalid(ErrorReason.INVALID_VALUE, f"String should match pattern '{pattern}'")
        return v

    return check


def nullable(inner: Check) -> Check:
    def check(v: Any) -> Any:
        return None if v is None else inner(v)

    return check


def all_floats(v: list[Any]) -> bool:
    return set(map(type, v)) <= {float}


def strings_between(lo: int, hi: int) -> Callable[[list[Any]], bool]:
    def fast(v: list[Any]) -> bool:
        return set(map(type, v)) <= {str} and (
            not v or (min(map(len, v)) >= lo and max(map(len, v)) <= hi)
        )

    return fast


def array(
    item: Check,
    min_length: int = 0,
    max_length: int | None = None,
    fast: Callable[[list[Any]], bool] | None = None,
) -> Check:
    """A list; too long is refused before the items are looked at, too short after.
    ``fast(v)`` True means every item passes ``item`` unchanged: one bulk test instead of a
    call per item (the per-item loop still finds the first bad one)."""

    def check(v: Any) -> list[Any]:
        if type(v) is not list:
            raise Invalid(ErrorReason.WRONG_TYPE, "Input should be a valid list")
        n = len(v)
        if max_length is not None and n > max_length:
            raise Invalid(
                ErrorReason.INVALID_VALUE,
                f"List should have at most {max_length} item{_plural(max_length)} after "
                f"validation, not {n}",
            )
        if fast is not None and n >= min_length and fast(v):
            return v
        out = []
        for i, x in enumerate(v):
            try:
                out.append(item(x))
            except Invalid as e:
                raise e.within(i) from None
        if n < min_length:
            raise Invalid(
                ErrorReason.INVALID_VALUE,
                f"List should have at least {min_length} item{_plural(min_length)} after "
                f"validation, not {n}",
            )
        return out

    return check


def one_of(enum: type[StrEnum]) -> Check:
    """A value of a string enumeration; a UTF-8 ``bin`` holding one is accepted too."""
    members = {m.value: m for m in enum}
    values = list(members)
    expected = ", ".join(f"'{v}'" for v in values[:-1]) + f" or '{values[-1]}'"

    def check(v: Any) -> StrEnum:
        if type(v) is bytes:
            with contextlib.suppress(UnicodeDecodeError):
                v = v.decode()
        member = members.get(v) if isinstance(v, str) else None  # a member is a str too
        if member is not None:
            return member
        raise Invalid(ErrorReason.INVALID_VALUE, f"Input should be {expected}")

    return check


def literal(value: int) -> Check:
    """Exactly ``value``; like pydantic, an equal bool or float matches too (the codec has
    already required ``schema_version`` to be an int)."""

    def check(v: Any) -> int:
        if type(v) in (int, bool, float) and v == value:
            return value
        if type(v) is int and not -(2**63) <= v < 2**63:
            raise Invalid(
                ErrorReason.INVALID_VALUE,
                "Unable to parse input string as an integer, exceeded maximum size",
            )
        raise Invalid(ErrorReason.WRONG_TYPE, f"Input should be {value}")

    return check


_EXACT: dict[Check, type] = {binary: bytes, boolean: bool}

REQUIRED: Any = object()  # a Field default: the key must be present
_ABSENT = object()


@dataclass(frozen=True, slots=True)
class Field:
    name: str
    check: Check
    default: Any = REQUIRED


class MapSpec(Generic[T]):
    """The fields of one map. Calling it (it is a ``Check``, so maps nest) validates a map and
    returns ``build(**fields)``, absent optional fields set to their defaults."""

    def __init__(self, name: str, build: Callable[..., T], fields: Sequence[Field]) -> None:
        self.name = name
        self._build = build
        # A check that is a bare type test is done inline for the valid case (columns are
        # most of a frame's fields); its function still reports the error.
        self._fields = tuple((f.name, f.check, f.default, _EXACT.get(f.check)) for f in fields)
        self._names = frozenset(f.name for f in fields)

    def __call__(self, obj: Any) -> T:
        if type(obj) is not dict:
            raise Invalid(
                ErrorReason.WRONG_TYPE,
                f"Input should be a valid dictionary or instance of {self.name}",
            )
        values: dict[str, Any] = {}
        present = 0
        for name, check, default, exact in self._fields:
            v = obj.get(name, _ABSENT)
            if type(v) is exact:
                present += 1
                values[name] = v
                continue
            if v is _ABSENT:
                if default is REQUIRED:
                    raise Invalid(ErrorReason.MISSING_FIELD, "Field required", (name,))
                values[name] = default
                continue
            present += 1
            try:
                values[name] = check(v)
            except Invalid as e:
                raise e.within(name) from None
        if len(obj) > present:
            for key in obj:
                if type(key) is not str:
                    raise Invalid(ErrorReason.INVALID_VALUE, "Keys should be strings", (str(key),))
                if key not in self._names:
                    raise Invalid(ErrorReason.EXTRA_FIELD, "Extra inputs are not permitted", (key,))
        return self._build(**values)
