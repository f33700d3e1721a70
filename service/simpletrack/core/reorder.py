"""A vehicle's frames wait here until they can go to its tracker in stamp order.

A frame is released once every other sensor of the vehicle that is live has sent a frame
stamped at or after it (each sensor's own frames arrive in stamp order, so nothing earlier
can still come from it), or once it has waited ``window_s``. Within the window, the order
frames are released in is their stamp order (ties: the configured sensor order, then seq),
whatever order they arrived in; a frame arriving later than that is late (the vehicle
tracker re-processes it, core/vehicle.py).

A sensor never heard, silent for ``silent_after_s``, or ``ignored`` (the vehicle keeps it
out: its clock or mounting is off) is not waited for: a dead camera delays the lidar's
frames by the window until it counts as silent, then not at all.

Pure: the caller passes its clock (``now``, seconds, monotonic).
"""

from __future__ import annotations

import heapq
import itertools
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Generic, TypeVar

T = TypeVar("T")


@dataclass(order=True, slots=True)
class _Waiting(Generic[T]):
    key: tuple[int, int, int]
    tie: int
    arrived: float = field(compare=False)
    sensor: str = field(compare=False)
    item: T = field(compare=False)


class ReorderBuffer(Generic[T]):
    def __init__(self, sensors: Sequence[str], window_s: float, silent_after_s: float) -> None:
        self.sensors = tuple(sensors)
        self.window_s, self.silent_after_s = window_s, silent_after_s
        self._index = {name: i for i, name in enumerate(self.sensors)}
        self._heap: list[_Waiting[T]] = []
        self._count = itertools.count()
        self._latest: dict[str, int] = {}  # newest stamp received per sensor
        self._heard: dict[str, float] = {}  # when its newest frame arrived
        self.ignored: frozenset[str] = frozenset()  # not waited for (kept out: flagged)

    def __len__(self) -> int:
        return len(self._heap)

    def push(self, sensor: str, seq: int, stamp_ns: int, item: T, now: float) -> None:
        key = (stamp_ns, self._index[sensor], seq)
        heapq.heappush(self._heap, _Waiting(key, next(self._count), now, sensor, item))
        self.assume_heard(sensor, stamp_ns, now)

    def assume_heard(self, sensor: str, stamp_ns: int, now: float) -> None:
        """Count ``sensor`` as heard at ``now``, its newest stamp ``stamp_ns``: a state taken
        over (its buffer new) waits for the sensors it had live, as the buffer it replaces
        did, instead of finding them silent and letting another sensor's frame go ahead of
        theirs stamped before it."""
        self._latest[sensor] = max(self._latest.get(sensor, stamp_ns), stamp_ns)
        self._heard[sensor] = now

    def silent(self, sensor: str, now: float) -> bool:
        heard = self._heard.get(sensor)
        return heard is None or now - heard > self.silent_after_s

    def _ready(self, w: _Waiting[T], now: float) -> bool:
        # The same sum as due()'s: a caller woken at the deadline finds the frame ready
        # (now - arrived rounds below window_s for some clock values).
        if now >= w.arrived + self.window_s:
            return True
        stamp = w.key[0]
        return all(
            s == w.sensor
            or s in self.ignored
            or self.silent(s, now)
            or self._latest.get(s, -1) >= stamp
            for s in self.sensors
        )

    def pop_ready(self, now: float) -> list[T]:
        """The frames that can go now, in order."""
        out: list[T] = []
        while self._heap and self._ready(self._heap[0], now):
            out.append(heapq.heappop(self._heap).item)
        return out

    def flush(self) -> list[T]:
        """Everything waiting, in order (a stop or a hand-off)."""
        out = [w.item for w in sorted(self._heap)]
        self._heap.clear()
        return out

    def due(self) -> float | None:
        """When the next frame goes at the latest (None: nothing waits): the first in order
        holds every other back, and it goes at the end of its window."""
        return None if not self._heap else self._heap[0].arrived + self.window_s


__all__ = ["ReorderBuffer"]
