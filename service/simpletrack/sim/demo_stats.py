"""Running figures of the live demo, per sensor stream and fleet-wide, in bounded memory."""

from __future__ import annotations

import math
from collections import Counter, deque
from dataclasses import dataclass, field

import numpy as np
import numpy.typing as npt

from simpletrack.sim.vehicle_score import FleetScores
from simpletrack.wire.keys import VEHICLE_STREAM

F64 = npt.NDArray[np.float64]


class LatencyHistogram:
    """Log-spaced bins from 10 µs to 100 s (1 % wide): quantiles over a whole run in fixed
    memory, exact to the bin width."""

    LOW, HIGH, BINS = 1e-5, 100.0, 1600

    def __init__(self) -> None:
        self.counts = np.zeros(self.BINS + 2, dtype=np.int64)  # + underflow, overflow
        self._log_low = math.log(self.LOW)
        self._scale = self.BINS / (math.log(self.HIGH) - self._log_low)
        self.n = 0

    def add(self, seconds: float) -> None:
        if seconds <= self.LOW:
            b = 0
        elif seconds >= self.HIGH:
            b = self.BINS + 1
        else:
            b = 1 + int((math.log(seconds) - self._log_low) * self._scale)
        self.counts[min(b, self.BINS)] += 1
        self.n += 1

    def quantile(self, q: float) -> float:
        """Upper edge of the bin holding the q-quantile; NaN when empty."""
        if self.n == 0:
            return float("nan")
        rank = max(1, math.ceil(q * self.n))
        b = int(np.searchsorted(np.cumsum(self.counts), rank))
        if b == 0:
            return self.LOW
        return math.exp(self._log_low + b / self._scale)


def recent_quantile(values: deque[float], q: float) -> float:
    return float(np.quantile(np.fromiter(values, float), q)) if values else float("nan")


@dataclass
class StreamStats:
    """One (vehicle, sensor) stream as the planner sees it."""

    vehicle: str
    sensor: str
    sent: int = 0
    tracked: int = 0
    rejected: Counter[str] = field(default_factory=Counter)
    tracks_now: int = 0
    confirmed_now: int = 0
    max_id: int = -1
    ids_seen: int = 0
    recent_latency: deque[float] = field(default_factory=lambda: deque(maxlen=200))
    arrivals: deque[float] = field(default_factory=lambda: deque(maxlen=256))

    @property
    def fused(self) -> bool:
        """The vehicle's fused stream (``@vehicle``), not a sensor's."""
        return self.sensor == VEHICLE_STREAM

    def on_tracks(
        self, now: float, latency_s: float, ids: npt.NDArray[np.int64], confirmed: int
    ) -> None:
        self.tracked += 1
        self.tracks_now = int(ids.shape[0])
        self.confirmed_now = confirmed
        # Ids are issued in increasing order and never reused: ids above the highest seen are new.
        new = ids[ids > self.max_id]
        if new.size:
            self.ids_seen += int(np.unique(new).size)
            self.max_id = int(new.max())
        self.recent_latency.append(latency_s)
        self.arrivals.append(now)

    def rate(self, now: float, window: float = 2.0) -> float:
        """Track frames per second over the last ``window`` seconds."""
        recent = [t for t in self.arrivals if now - t <= window]
        if len(recent) < 2:
            return 0.0
        return (len(recent) - 1) / max(recent[-1] - recent[0], 1e-9)


@dataclass
class FleetStats:
    """The fleet as planners see it: per stream (each sensor's, each vehicle's fused), and
    every vehicle's rows scored against its truth (``scores``)."""

    scores: FleetScores
    streams: dict[tuple[str, str], StreamStats] = field(default_factory=dict)
    latency: LatencyHistogram = field(default_factory=LatencyHistogram)
    fused_latency: LatencyHistogram = field(default_factory=LatencyHistogram)

    def stream(self, vehicle: str, sensor: str) -> StreamStats:
        key = (vehicle, sensor)
        if key not in self.streams:
            self.streams[key] = StreamStats(vehicle, sensor)
        return self.streams[key]

    @property
    def sent(self) -> int:
        return sum(s.sent for s in self.streams.values())

    @property
    def tracked(self) -> int:
        """Sensors' frames answered with their own tracks."""
        return sum(s.tracked for s in self.streams.values() if not s.fused)

    @property
    def fused_messages(self) -> int:
        return sum(s.tracked for s in self.streams.values() if s.fused)

    @property
    def rejected(self) -> Counter[str]:
        total: Counter[str] = Counter()
        for s in self.streams.values():
            total.update(s.rejected)
        return total

    @property
    def tracks_now(self) -> int:
        """Fused tracks held now (each vehicle's one list)."""
        return sum(s.tracks_now for s in self.streams.values() if s.fused)

    @property
    def ids_seen(self) -> int:
        return sum(s.ids_seen for s in self.streams.values() if s.fused)
