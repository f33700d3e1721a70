"""The service's two conversions between wire columns and the core's frames and tracks.

Kept as they were when the worker was split; simpletrack.wire's wire<->core adapter is due to
replace them.
"""

from __future__ import annotations

import numpy as np

from simpletrack.core.boxes import Boxes
from simpletrack.core.frames import Frame, Tracks
from simpletrack.core.lifecycle import TrackState
from simpletrack.wire.codec import DecodedDetections
from simpletrack.wire.columns import TrackArrays
from simpletrack.wire.reasons import WireTrackState


def tracks_to_wire(tracks: Tracks, id_base: int, classes: tuple[str, ...]) -> TrackArrays:
    p = tracks.boxes.params
    confirmed = tracks.state == TrackState.CONFIRMED
    state = np.where(
        confirmed,
        np.where(tracks.time_since_update > 0, WireTrackState.COASTING, WireTrackState.CONFIRMED),
        WireTrackState.TENTATIVE,
    ).astype(np.int32)
    return TrackArrays(
        classes=classes,
        id=tracks.ids + np.int64(id_base),
        class_index=tracks.boxes.cls.astype(np.int32),
        center=p[:, 0:3].astype(np.float32),
        size=p[:, 4:7].astype(np.float32),
        yaw=p[:, 3].astype(np.float32),
        score=tracks.boxes.score,
        velocity=tracks.velocity.astype(np.float32),
        state=state,
        hits=tracks.hits.astype(np.int32),
        age=tracks.age.astype(np.int32),
        time_since_update=tracks.time_since_update.astype(np.int32),
    )


def detections_to_frame(d: DecodedDetections, stamp: float) -> tuple[Frame, int]:
    """The tracker's frame (float64, z-up x, y, z, yaw, l, w, h) and how many boxes of
    ignored classes were left out."""
    b = d.boxes
    codes = d.codes if d.codes is not None else b.class_index
    keep = codes >= 0
    params = np.concatenate([b.center, b.yaw[:, None], b.size], axis=1).astype(np.float64)
    boxes = Boxes.from_arrays(params, b.score, codes, b.velocity)
    ignored = int(len(b) - int(keep.sum()))
    if ignored:
        boxes = boxes.take(keep)
    return Frame(boxes=boxes, stamp=stamp, pose=d.pose, key_frame=d.frame.key_frame), ignored
