"""``simpletrack record --format mcap``: the argument parsing of the recording (the writer is
simpletrack.mcap.writer; ``--ros2``'s messages are simpletrack.ros2.recording's)."""

from __future__ import annotations

from simpletrack.cli.errors import UserError
from simpletrack.client.publisher import check_name
from simpletrack.wire.keys import VEHICLE_STREAM


def parse_sensors(values: list[str] | None) -> list[tuple[str, str]]:
    """``vehicle/sensor`` pairs (``*`` allowed in either place), comma- or space-separated;
    ``vehicle/@vehicle`` names a fused vehicle's tracks stream."""
    items = [s.strip() for v in values or ["*/*"] for s in v.split(",") if s.strip()]
    out = []
    for item in items:
        vehicle, _, sensor = item.partition("/")
        try:
            for kind, name in (("vehicle", vehicle), ("sensor", sensor)):
                if name != "*" and not (kind == "sensor" and name == VEHICLE_STREAM):
                    check_name(kind, name)
        except ValueError as exc:
            raise UserError(
                f"--sensors {item!r}: expected vehicle/sensor or vehicle/{VEHICLE_STREAM}; {exc}"
            ) from None
        out.append((vehicle, sensor))
    return out


def parse_what(text: str, choices: tuple[str, ...]) -> list[str]:
    what = [w.strip() for w in text.split(",") if w.strip()]
    for w in what:
        if w not in choices:
            raise UserError(f"--what {w!r}: choose from {', '.join(choices)}")
    if not what:
        raise UserError("--what is empty")
    return list(dict.fromkeys(what))
