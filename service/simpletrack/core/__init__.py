"""The pure SimpleTrack core: numpy arrays in, numpy arrays out; no I/O, clocks or environment."""

from simpletrack.core.boxes import Boxes
from simpletrack.core.config import (
    ClassConfig,
    Matcher,
    Metric,
    MotionModel,
    OutputPolicy,
    TieOrder,
    TrackerConfig,
    TrackScore,
    VerticalOverlap,
    preset,
)
from simpletrack.core.frames import Frame, Tracks
from simpletrack.core.tracker import Tracker

__all__ = [
    "Boxes",
    "ClassConfig",
    "Frame",
    "Matcher",
    "Metric",
    "MotionModel",
    "OutputPolicy",
    "TieOrder",
    "TrackScore",
    "Tracker",
    "TrackerConfig",
    "Tracks",
    "VerticalOverlap",
    "preset",
]
