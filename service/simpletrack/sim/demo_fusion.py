"""The live demo's scoring of what a vehicle's planner receives (``vehicle_score``): at each
stamp where every sensor of a vehicle has a frame, the truth and the detections are noted
when the frames are made; each sensor's tracks and the vehicle's fused tracks are noted as
they arrive; a stamp is scored once the fused tracks have moved past it (fused messages come
in stamp order, so every input at that stamp has been applied) and every sensor's tracks of
it are in (or its frame was refused).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from simpletrack.client.subscriber import TrackMessage, VehicleTrackMessage
from simpletrack.core.config import TrackerConfig
from simpletrack.sim.baseline import detections_alone
from simpletrack.sim.simulator import SensorFrame
from simpletrack.sim.vehicle_score import FleetScores, Stamp
from simpletrack.wire import FrameError

HORIZON = 400  # stamps kept per vehicle while their tracks are awaited


@dataclass
class VehicleCollector:
    scores: FleetScores
    config: TrackerConfig
    sensors: tuple[str, ...]
    _pending: dict[str, dict[int, Stamp]] = field(default_factory=dict)  # vehicle -> stamp_ns
    _fused_at: dict[str, int] = field(default_factory=dict)  # vehicle -> newest fused stamp

    def expect(self, frames: list[SensorFrame], stamp_ns: int) -> None:
        """One vehicle's frames of one tick, as they are made: scored when every sensor
        has one."""
        if len(frames) != len(self.sensors):
            return
        stamp = Stamp.of(frames)
        for f in frames:
            stamp.detections[f.sensor] = detections_alone(f.detections, f.pose, self.config)
        pending = self._pending.setdefault(frames[0].vehicle, {})
        pending[stamp_ns] = stamp
        while len(pending) > HORIZON:
            del pending[min(pending)]  # its tracks never came: lost, not leaked

    def sensor_tracks(self, msg: TrackMessage, classes: tuple[str, ...]) -> None:
        stamp = self._pending.get(msg.vehicle, {}).get(msg.stamp_ns)
        if stamp is not None:
            stamp.tracks[msg.sensor] = (msg.tracks.id.astype(np.int64), msg.boxes(classes))
            self._score_ready(msg.vehicle)

    def vehicle_tracks(self, msg: VehicleTrackMessage, classes: tuple[str, ...]) -> None:
        stamp = self._pending.get(msg.vehicle, {}).get(msg.stamp_ns)
        if stamp is not None:  # a later message at one stamp saw more of it: it wins
            stamp.fused = (msg.tracks.id.astype(np.int64), msg.boxes(classes), msg.existence)
        self._fused_at[msg.vehicle] = max(self._fused_at.get(msg.vehicle, -1), msg.stamp_ns)
        self._score_ready(msg.vehicle)

    def refused(self, err: FrameError) -> None:
        """A frame refused is no sensor's tracks to wait for."""
        if err.stamp_ns is None:
            return
        stamp = self._pending.get(err.vehicle, {}).get(err.stamp_ns)
        if stamp is not None:
            stamp.expected.discard(err.sensor)
            self._score_ready(err.vehicle)

    def _score_ready(self, vehicle: str) -> None:
        pending = self._pending.get(vehicle, {})
        fused_at = self._fused_at.get(vehicle, -1)
        for t in sorted(pending):
            stamp = pending[t]
            if t >= fused_at or not stamp.expected <= set(stamp.tracks):
                break
            del pending[t]
            if stamp.fused is not None:  # else no row is scored: all rows share frames
                self.scores.vehicle(vehicle).score(stamp)

    def flush(self) -> None:
        """At the end: every stamp whose tracks all came (fused ones included)."""
        for vehicle, pending in self._pending.items():
            for t in sorted(pending):
                stamp = pending[t]
                if stamp.fused is not None and stamp.expected <= set(stamp.tracks):
                    self.scores.vehicle(vehicle).score(stamp)
            pending.clear()


__all__ = ["VehicleCollector"]
