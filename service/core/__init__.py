"""The pure SimpleTrack core: numpy arrays in, numpy arrays out; no I/O, clocks or environment."""

from service.core.boxes import Boxes
from service.core.config import (
    ClassConfig,
    Matcher,
    Metric,
    MotionModel,
    OutputPolicy,
    TieOrder,
    TrackerConfig,
    VerticalOverlap,
    preset,
)

__all__ = [
    "Boxes",
    "ClassConfig",
    "Matcher",
    "Metric",
    "MotionModel",
    "OutputPolicy",
    "TieOrder",
    "TrackerConfig",
    "VerticalOverlap",
    "preset",
]
