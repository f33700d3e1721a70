"""One-line messages for pydantic validation errors: what the operator of ``simpletrack serve``
reads when a setting is wrong."""

from __future__ import annotations

from pydantic import ValidationError


def format_error(e: ValidationError, prefix: str = "") -> str:
    """One line per problem: ``field: message (got value)``; ``prefix`` is put before every
    field name (``tracker.``)."""
    parts = []
    for err in e.errors(include_url=False):
        loc = prefix + ".".join(str(p) for p in err["loc"])
        if not err["loc"]:
            # A check of the whole model: its own message names the values; its input is
            # every setting, too much to echo.
            cause = err.get("ctx", {}).get("error")
            msg = str(cause) if cause is not None else err["msg"]
            parts.append(f"{loc.rstrip('.')}: {msg}" if loc else msg)
            continue
        got = f" (got {err['input']!r})" if err["type"] != "missing" else ""
        parts.append(f"{loc}: {err['msg']}{got}")
    return "; ".join(parts)
