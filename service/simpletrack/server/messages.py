"""One-line messages for pydantic validation errors: what the operator of ``simpletrack serve``
reads when a setting is wrong."""

from __future__ import annotations

from collections.abc import Callable

from pydantic import ValidationError

# Where a problem's value was written (``file:line:column``), from its location and message.
Where = Callable[[tuple[str | int, ...], str], str | None]


def format_error(e: ValidationError, prefix: str = "", where: Where | None = None) -> str:
    """One line per problem: ``field: message (got value)``; ``prefix`` is put before every
    field name (``tracker.``); ``where`` may put the place of the value before a problem."""
    parts = []
    for err in e.errors(include_url=False):
        loc = prefix + ".".join(str(p) for p in err["loc"])
        if not err["loc"]:
            # A check of the whole model: its own message names the values; its input is
            # every setting, too much to echo.
            cause = err.get("ctx", {}).get("error")
            msg = str(cause) if cause is not None else err["msg"]
            part = f"{loc.rstrip('.')}: {msg}" if loc else msg
        else:
            got = f" (got {err['input']!r})" if err["type"] != "missing" else ""
            part = f"{loc}: {err['msg']}{got}"
        place = where(tuple(err["loc"]), part) if where is not None else None
        parts.append(f"{place}: {part}" if place else part)
    return "; ".join(parts)
