"""What goes into and comes out of Tracker.step."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from simpletrack.core.boxes import F64, Boxes, transform_boxes

I64 = npt.NDArray[np.int64]
I32 = npt.NDArray[np.int32]
I8 = npt.NDArray[np.int8]
# Rows/columns of the 10-d Kalman state that Tracks.covariance keeps: x, y, z, vx, vy, vz.
POS_VEL = (0, 1, 2, 7, 8, 9)


@dataclass(frozen=True, slots=True)
class Frame:
    """One sensor frame of detections. ``stamp`` in seconds (any monotonic origin);
    ``pose`` an optional 4x4 sensor->world transform; ``key_frame`` False marks the
    paper's 10 Hz non-key frames. ``after_gap`` marks the first frame after a gap in the
    stream that the caller bridged (an outage, not a new stream): detections and tracks the
    ordinary stages leave apart are re-associated across it (core/reassociation.py)."""

    boxes: Boxes
    stamp: float
    pose: F64 | None = None
    key_frame: bool = True
    after_gap: bool = False


@dataclass(frozen=True, slots=True)
class Tracks:
    """The tracks a frame reports, in the tracking frame (world when a pose is given).

    ``boxes.score`` is the output score; ``velocity`` (K, 3) the filter's; ``state`` holds
    TrackState codes; ``update`` UpdateKind codes for this frame. ``covariance`` (K, 6, 6)
    is the Kalman filter's over ``POS_VEL`` = [x, y, z, vx, vy, vz] for the reported box
    (updated for a corrected track, predicted for a coasting one); None under
    ``motion=cv``, which keeps none. ``age_s`` and ``time_since_update_s`` are seconds from
    the track's birth and from its last update to this frame's stamp."""

    ids: I64
    boxes: Boxes
    velocity: F64
    state: I8
    update: I8
    hits: I32
    age: I32
    time_since_update: I32
    covariance: F64 | None = None
    age_s: F64 | None = None
    time_since_update_s: F64 | None = None

    def __len__(self) -> int:
        return int(self.ids.shape[0])

    @classmethod
    def empty(cls) -> Tracks:
        return cls(
            ids=np.zeros(0, dtype=np.int64),
            boxes=Boxes.empty(),
            velocity=np.zeros((0, 3)),
            state=np.zeros(0, dtype=np.int8),
            update=np.zeros(0, dtype=np.int8),
            hits=np.zeros(0, dtype=np.int32),
            age=np.zeros(0, dtype=np.int32),
            time_since_update=np.zeros(0, dtype=np.int32),
            age_s=np.zeros(0),
            time_since_update_s=np.zeros(0),
        )

    def in_sensor_frame(self, pose: F64) -> Tracks:
        """These tracks expressed in the sensor frame whose sensor->world pose is given."""
        inv = np.asarray(np.linalg.inv(pose), dtype=np.float64)
        boxes = transform_boxes(self.boxes, inv)
        rot = inv[:3, :3]
        vel = self.velocity @ rot.T
        cov = None
        if self.covariance is not None:
            # Positions and velocities both turn by the rotation; the translation moves no
            # uncertainty.
            b = np.zeros((6, 6))
            b[:3, :3] = b[3:, 3:] = rot
            cov = np.einsum("ij,tjk,lk->til", b, self.covariance, b)
        return Tracks(
            ids=self.ids,
            boxes=boxes,
            velocity=vel,
            state=self.state,
            update=self.update,
            hits=self.hits,
            age=self.age,
            time_since_update=self.time_since_update,
            covariance=cov,
            age_s=self.age_s,
            time_since_update_s=self.time_since_update_s,
        )
