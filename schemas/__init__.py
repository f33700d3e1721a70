"""The wire contract of the SimpleTrack service (spec: schemas/README.md)."""

from schemas.codec import (
    DecodedDetections,
    DecodeLimits,
    Rejection,
    decode_detection_frame,
    decode_message,
    decode_track_frame,
    encode,
    encode_detection_frame,
    encode_track_frame,
)
from schemas.columns import BoxArrays, TrackArrays
from schemas.models import (
    BoxColumns,
    DetectionFrame,
    FrameError,
    SensorSnapshot,
    SensorStatus,
    ServiceStatus,
    TrackColumns,
    TrackFrame,
)
from schemas.reasons import SCHEMA_VERSION, ErrorReason, WireTrackState

__all__ = [
    "SCHEMA_VERSION",
    "BoxArrays",
    "BoxColumns",
    "DecodeLimits",
    "DecodedDetections",
    "DetectionFrame",
    "ErrorReason",
    "FrameError",
    "Rejection",
    "SensorSnapshot",
    "SensorStatus",
    "ServiceStatus",
    "TrackArrays",
    "TrackColumns",
    "TrackFrame",
    "WireTrackState",
    "decode_detection_frame",
    "decode_message",
    "decode_track_frame",
    "encode",
    "encode_detection_frame",
    "encode_track_frame",
]
