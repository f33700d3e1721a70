"""The in-process tracking hook of the KITTI evaluation (``simpletrack eval kitti`` and the
tuning sweep): frames of one sequence in, the tracker's output for each frame out."""

from __future__ import annotations

from collections.abc import Sequence

from simpletrack.core.config import TrackerConfig
from simpletrack.core.frames import Frame, Tracks
from simpletrack.datasets.kitti import SequenceFrame


def track_sequence(frames: Sequence[SequenceFrame], config: TrackerConfig) -> list[Tracks]:
    """The tracker's output for every frame of one sequence, in order (in-process).

    This is the hook for other transports: a Zenoh path takes the same frames and config and
    returns the same list."""
    from simpletrack.core.tracker import Tracker  # the tracker's import cost only when tracking

    tracker = Tracker(config)
    return [tracker.step(Frame(boxes=f.boxes, stamp=f.stamp)) for f in frames]
