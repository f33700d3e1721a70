"""What every decoder shares: the byte cap and msgpack read, the version check, the field
tables' verdict, the columns' lengths and finiteness, and the ``Rejection`` it ends in
(order of checks: schemas/README.md, "Validation order and reasons")."""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any, TypeVar

import msgpack
import numpy as np
import numpy.typing as npt

from simpletrack.wire.columns import ColumnSpec
from simpletrack.wire.fields import Invalid, MapSpec
from simpletrack.wire.reasons import SCHEMA_VERSION, ErrorReason

T = TypeVar("T")
# The reductions themselves, without ndarray.min's Python wrapper (a frame reads a dozen).
_least = np.minimum.reduce
_greatest = np.maximum.reduce


@dataclass(frozen=True, slots=True)
class DecodeLimits:
    max_bytes: int = 8 << 20
    max_boxes: int = 10_000


DEFAULT_LIMITS = DecodeLimits()  # the service's defaults


@dataclass(frozen=True, slots=True)
class Rejection:
    """Why a payload was refused; ``seq``/``stamp_ns`` when they could still be read."""

    reason: ErrorReason
    field: str | None
    detail: str
    seq: int | None = None
    stamp_ns: int | None = None


class Reject(Exception):
    """The first failing check inside a decoder; its boundary turns it into a Rejection."""

    def __init__(self, reason: ErrorReason, field: str | None, detail: str) -> None:
        super().__init__(detail)
        self.reason, self.field, self.detail = reason, field, detail


def unpack(payload: bytes, limits: DecodeLimits) -> dict[str, Any]:
    if len(payload) > limits.max_bytes:
        raise Reject(
            ErrorReason.TOO_LARGE,
            "payload",
            f"{len(payload)} bytes exceeds the cap of {limits.max_bytes}",
        )
    try:
        obj = msgpack.unpackb(payload, raw=False, strict_map_key=True)
    except (ValueError, TypeError, msgpack.UnpackException, RecursionError, OverflowError) as e:
        # ExtraData, FormatError, StackError and bad UTF-8 are all ValueError subclasses.
        raise Reject(ErrorReason.MALFORMED, "payload", f"not msgpack: {e}"[:200]) from None
    if not isinstance(obj, dict):
        raise Reject(ErrorReason.MALFORMED, "payload", f"expected a map, got {type(obj).__name__}")
    return obj


def check_version(obj: dict[str, Any], accepted: tuple[int, ...] = (SCHEMA_VERSION,)) -> int:
    version = obj.get("schema_version")
    if "schema_version" not in obj:
        raise Reject(ErrorReason.MISSING_FIELD, "schema_version", "field required")
    if type(version) is not int:
        raise Reject(ErrorReason.WRONG_TYPE, "schema_version", "must be an integer")
    if version not in accepted:
        speaks = ", ".join(map(str, accepted))
        raise Reject(
            ErrorReason.WRONG_VERSION,
            "schema_version",
            f"version {version} not supported (this service speaks {speaks})",
        )
    return version


def validate(spec: MapSpec[T], obj: dict[str, Any]) -> T:
    try:
        return spec(obj)
    except Invalid as e:
        raise Reject(e.reason, e.field, e.detail[:200]) from None


def peek_int(obj: Mapping[str, Any], key: str) -> int | None:
    v = obj.get(key)
    return v if type(v) is int and 0 <= v < 2**63 else None


def rejection(r: Reject, obj: Mapping[str, Any]) -> Rejection:
    """The Rejection of a frame, naming its seq and stamp when the map held them."""
    return Rejection(r.reason, r.field, r.detail, peek_int(obj, "seq"), peek_int(obj, "stamp_ns"))


def internal_error(e: Exception) -> Rejection:
    """A bug in a decoder, reported rather than raised (the fuzz tests assert it never is)."""
    return Rejection(ErrorReason.INTERNAL_ERROR, None, f"{type(e).__name__}: {e}"[:300])


@dataclass(frozen=True, slots=True)
class Column:
    """A column spec with what decoding needs per frame worked out once."""

    name: str
    field: str  # dotted, for rejections
    dtype: np.dtype[Any]
    row_bytes: int  # a per-sensor column's: one value's
    width: int
    finite: bool
    per_sensor: bool


def plan(specs: tuple[ColumnSpec, ...], prefix: str) -> tuple[Column, ...]:
    return tuple(
        Column(
            s.name,
            f"{prefix}.{s.name}",
            np.dtype(s.dtype),
            s.row_bytes,
            s.width,
            s.finite,
            s.per_sensor,
        )
        for s in specs
    )


Extents = dict[str, tuple[float, float]]  # a float column's (least, greatest) value


def read_columns(
    model: Any,
    plan: tuple[Column, ...],
    prefix: str,
    max_rows: int,
    sensors: int = 0,
    extents: Extents | None = None,
) -> dict[str, npt.NDArray[Any]]:
    """The columns of a map, in table order: the row cap, then per column its byte length
    (``count`` rows, a per-sensor column ``sensors`` values wide) and finiteness. Given
    ``extents``, each finite column of at least one row is judged by its least and greatest
    value instead (NaN and inf reach them), which are stored there: the later checks of the
    values' bounds and their plausibility read them instead of reducing the column again."""
    count = int(model.count)
    if count > max_rows:
        raise Reject(
            ErrorReason.TOO_LARGE, f"{prefix}.count", f"{count} rows exceeds the cap of {max_rows}"
        )
    out: dict[str, npt.NDArray[Any]] = {}
    for c in plan:
        buf = getattr(model, c.name)
        if buf is None:
            continue
        width = sensors if c.per_sensor else c.width
        row_bytes = c.row_bytes * sensors if c.per_sensor else c.row_bytes
        if len(buf) != count * row_bytes:
            expected = (
                f"count {count} x {sensors} sensors x {c.row_bytes} bytes"
                if c.per_sensor
                else f"count {count} x {c.row_bytes} bytes"
            )
            raise Reject(
                ErrorReason.COLUMN_LENGTH, c.field, f"{len(buf)} bytes, expected {expected}"
            )
        arr = np.frombuffer(buf, dtype=c.dtype)  # what view_column does, minus its lookups
        if c.per_sensor or c.width > 1:
            arr = arr.reshape(count, width)
        if c.finite:
            if extents is not None and count:
                lo = float(_least(arr, axis=None))
                hi = float(_greatest(arr, axis=None))
                finite = math.isfinite(lo) and math.isfinite(hi)
                extents[c.name] = (lo, hi)
            else:
                finite = bool(np.isfinite(arr).all())
            if not finite:
                row = int(np.argwhere(~np.isfinite(arr))[0][0])
                raise Reject(ErrorReason.NON_FINITE, c.field, f"NaN or inf in row {row}")
        out[c.name] = arr
    return out
