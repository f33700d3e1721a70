"""The wire contract of the SimpleTrack service (spec: schemas/README.md).

Light: numpy and msgpack only. The pydantic models (JSON Schemas, the server's replies) are
in ``simpletrack.wire.models``, which nothing here imports."""

from simpletrack.wire.codec import (
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
from simpletrack.wire.columns import BoxArrays, TrackArrays
from simpletrack.wire.messages import (
    BoxColumns,
    DetectionFrame,
    FrameError,
    FusedSensorStatus,
    SensorSnapshot,
    SensorStatus,
    ServiceStatus,
    TrackColumns,
    TrackFrame,
    VehicleStatus,
    VehicleTrackColumns,
    VehicleTrackFrame,
)
from simpletrack.wire.reasons import SCHEMA_VERSION, ErrorReason, SensorCondition, WireTrackState
from simpletrack.wire.vehicle_tracks import (
    decode_vehicle_track_frame,
    encode_vehicle_track_frame,
)

__all__ = [
    "SCHEMA_VERSION",
    "BoxArrays",
    "BoxColumns",
    "DecodeLimits",
    "DecodedDetections",
    "DetectionFrame",
    "ErrorReason",
    "FrameError",
    "FusedSensorStatus",
    "Rejection",
    "SensorCondition",
    "SensorSnapshot",
    "SensorStatus",
    "ServiceStatus",
    "TrackArrays",
    "TrackColumns",
    "TrackFrame",
    "VehicleStatus",
    "VehicleTrackColumns",
    "VehicleTrackFrame",
    "WireTrackState",
    "decode_detection_frame",
    "decode_message",
    "decode_track_frame",
    "decode_vehicle_track_frame",
    "encode",
    "encode_detection_frame",
    "encode_track_frame",
    "encode_vehicle_track_frame",
]
