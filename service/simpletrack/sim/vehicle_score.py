"""What a vehicle's planner gets, scored against the vehicle's truth: every object in view of
any of its sensors (``SensorFrame.vehicle_truth``), at the stamps where every sensor of the
vehicle has a frame (a 10 Hz lidar and a 15 Hz camera: every 0.2 s), so that every row is
scored on the same frames and the same truth:

- ``fused``: the vehicle's fused tracks (the last message at that stamp);
- ``together``: every sensor's own tracks at that stamp taken together, ids kept apart by
  sensor (what a planner subscribing to ``<prefix>/<vehicle>/*/tracks`` has today);
- one row per sensor: that sensor's own tracks alone;
- ``detections``: every sensor's raw detections at that stamp (``baseline.py``: score_high,
  NMS, no ids; IDS not counted).

Pure bookkeeping over ``MotScorer``: the live demo and the settings sweep both use it.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np
import numpy.typing as npt

from simpletrack.core.boxes import Boxes
from simpletrack.eval.clear_mot import MotCounts, MotScorer
from simpletrack.sim.baseline import without_identity

if TYPE_CHECKING:
    from simpletrack.sim.simulator import SensorFrame

I64 = npt.NDArray[np.int64]
F64 = npt.NDArray[np.float64]
FUSED, TOGETHER, DETECTIONS = "fused", "together", "detections"
_SENSOR_ID_SPAN = 1 << 40  # sensor j's track ids + j * span: one id space for "together"
CALIBRATION_BINS = 10
# Scoring stamps (5 Hz) an object may be out of every view and still be the same object
# when it comes back: longer, and no tracker without re-identification could have kept it.
FORGET_AFTER = 10


@dataclass
class Stamp:
    """Everything of one vehicle at one stamp."""

    truth_ids: I64
    truth: Boxes
    truth_ignore: npt.NDArray[np.bool_]
    expected: set[str]  # the sensors with a frame at this stamp
    detections: dict[str, Boxes] = field(default_factory=dict)  # world frame, baseline kept
    tracks: dict[str, tuple[I64, Boxes]] = field(default_factory=dict)
    fused: tuple[I64, Boxes, F64] | None = None  # ids, boxes, existence

    @classmethod
    def of(cls, frames: Sequence[SensorFrame]) -> Stamp:
        """The stamp of one vehicle's frames of one tick (its truth is theirs)."""
        first = frames[0]
        return cls(
            first.vehicle_truth_ids,
            first.vehicle_truth,
            np.asarray(first.vehicle_truth_ignore),
            {f.sensor for f in frames},
        )


def _concat(parts: list[Boxes]) -> Boxes:
    if not parts:
        return Boxes.empty()
    return Boxes(
        params=np.concatenate([b.params for b in parts]),
        score=np.concatenate([b.score for b in parts]),
        cls=np.concatenate([b.cls for b in parts]).astype(np.int32),
    )


@dataclass
class VehicleScores:
    """One vehicle's rows (one scorer each, so ids never mix between vehicles)."""

    sensors: tuple[str, ...]
    scorers: dict[str, MotScorer] = field(default_factory=dict)
    detection_ids: int = 0
    # Existence calibration of the fused tracks: per bin of reported existence, tracks and
    # how many of them matched a truth object.
    reported: npt.NDArray[np.int64] = field(
        default_factory=lambda: np.zeros(CALIBRATION_BINS, np.int64)
    )
    real: npt.NDArray[np.int64] = field(
        default_factory=lambda: np.zeros(CALIBRATION_BINS, np.int64)
    )

    def __post_init__(self) -> None:
        for row in (FUSED, TOGETHER, *self.sensors, DETECTIONS):
            self.scorers.setdefault(row, MotScorer(forget_after=FORGET_AFTER))

    def score(self, s: Stamp) -> None:
        """Score one complete stamp (every sensor's tracks in, the fused tracks final)."""
        args = (s.truth_ids, s.truth)
        if s.fused is not None:
            ids, boxes, existence = s.fused
            self.scorers[FUSED].update(*args, ids, boxes, s.truth_ignore)
            self._calibrate(s, boxes, existence)
        together_ids, together_boxes = [], []
        for j, sensor in enumerate(self.sensors):
            ids, boxes = s.tracks.get(sensor, (np.zeros(0, np.int64), Boxes.empty()))
            self.scorers[sensor].update(*args, ids, boxes, s.truth_ignore)
            together_ids.append(ids + j * _SENSOR_ID_SPAN)
            together_boxes.append(boxes)
        self.scorers[TOGETHER].update(
            *args, np.concatenate(together_ids), _concat(together_boxes), s.truth_ignore
        )
        dets = _concat([s.detections[x] for x in self.sensors if x in s.detections])
        fresh = np.arange(self.detection_ids, self.detection_ids + len(dets), dtype=np.int64)
        self.detection_ids += len(dets)
        self.scorers[DETECTIONS].update(*args, fresh, dets, s.truth_ignore)

    def _calibrate(self, s: Stamp, boxes: Boxes, existence: F64) -> None:
        """Which reported fused tracks are real objects (within the scorer's gate of a truth
        box of their class, ignored truth included)."""
        if len(boxes) == 0:
            return
        d = np.linalg.norm(boxes.params[:, None, :3] - s.truth.params[None, :, :3], axis=2)
        same = boxes.cls[:, None] == s.truth.cls[None, :]
        gate = self.scorers[FUSED].max_distance
        real = (same & (d <= gate)).any(axis=1) if len(s.truth) else np.zeros(len(boxes), bool)
        bins = np.minimum((existence * CALIBRATION_BINS).astype(np.int64), CALIBRATION_BINS - 1)
        np.add.at(self.reported, bins, 1)
        np.add.at(self.real, bins[real], 1)

    def counts(self, row: str) -> MotCounts:
        c = self.scorers[row].counts
        return without_identity(c) if row == DETECTIONS else c


@dataclass
class FleetScores:
    sensors: tuple[str, ...]
    vehicles: dict[str, VehicleScores] = field(default_factory=dict)

    def vehicle(self, vehicle: str) -> VehicleScores:
        if vehicle not in self.vehicles:
            self.vehicles[vehicle] = VehicleScores(self.sensors)
        return self.vehicles[vehicle]

    @property
    def rows(self) -> tuple[str, ...]:
        return (FUSED, TOGETHER, *self.sensors, DETECTIONS)

    def counts(self, row: str) -> MotCounts:
        return sum((v.counts(row) for v in self.vehicles.values()), MotCounts())

    def calibration(self) -> list[tuple[float, int, float]]:
        """(bin's lower edge, tracks, share real) per existence bin with tracks."""
        reported = sum((v.reported for v in self.vehicles.values()), np.zeros(CALIBRATION_BINS))
        real = sum((v.real for v in self.vehicles.values()), np.zeros(CALIBRATION_BINS))
        return [
            (b / CALIBRATION_BINS, int(n), float(real[b] / n))
            for b, n in enumerate(reported.tolist())
            if n
        ]


__all__ = ["DETECTIONS", "FUSED", "TOGETHER", "FleetScores", "Stamp", "VehicleScores"]
