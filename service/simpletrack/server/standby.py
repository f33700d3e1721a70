"""What a worker keeps of the sensors it stands by for: the owner's latest checkpoint and the
frames heard since it, so that taking a sensor over is restore, then replay.

Bounded: at most ``max_frames`` frames per sensor (the oldest go first; a takeover then
finds the gap and fills it from the vehicle's cache, or announces it), trimmed to the frames
after each checkpoint.
Only the worker's thread uses it.
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass, field

from simpletrack.server.intake import Inbound, stamp_of
from simpletrack.wire.models import SensorSnapshot

MAX_STANDBY_SENSORS = 100_000


@dataclass(slots=True)
class _Held:
    checkpoint: SensorSnapshot | None = None
    frames: deque[tuple[int | None, Inbound]] = field(default_factory=deque)  # (stamp, frame)


class Standby:
    def __init__(self, max_frames: int) -> None:
        self.max_frames = max_frames
        self._held: dict[str, _Held] = {}

    def __len__(self) -> int:
        return len(self._held)

    def _get(self, sensor: str) -> _Held | None:
        held = self._held.get(sensor)
        if held is None:
            if len(self._held) >= MAX_STANDBY_SENSORS:
                return None
            held = self._held[sensor] = _Held()
        return held

    def keep(self, sensor: str, item: Inbound) -> None:
        held = self._get(sensor)
        if held is None:
            return
        held.frames.append((stamp_of(item), item))
        if len(held.frames) > self.max_frames:
            held.frames.popleft()  # a takeover finds the gap and asks the vehicle's cache

    def checkpoint(self, sensor: str, snap: SensorSnapshot) -> None:
        """The owner's state: frames it covers are no longer needed."""
        held = self._get(sensor)
        if held is None:
            return
        old = held.checkpoint
        if old is not None and old.written_ns > snap.written_ns:
            return  # an older one overtaken on the way
        held.checkpoint = snap
        last = snap.last_stamp_ns
        if last is not None:
            while held.frames and (held.frames[0][0] or 0) <= last:
                held.frames.popleft()

    def take(self, sensor: str) -> tuple[SensorSnapshot | None, list[Inbound]]:
        """Everything kept of ``sensor`` (forgotten here): checkpoint and frames in
        arrival order."""
        held = self._held.pop(sensor, None)
        if held is None:
            return None, []
        return held.checkpoint, [item for _, item in held.frames]

    def forget(self, sensor: str) -> None:
        self._held.pop(sensor, None)

    def sensors(self) -> list[str]:
        return list(self._held)


__all__ = ["Standby"]
