//! The wire format (schemas/README.md): typed messages, their msgpack encoders (byte for byte
//! the reference encoder's output) and validating decoders (the reference decoder's verdicts:
//! the same reason and field for the first failing check). Schema version 1, except
//! `DetectionFrame` (1 and 2: the extrinsic), `TrackFrame` (1 to 3: 3 the custody epoch),
//! `ServiceStatus` (1 and 2: the fused vehicles) and `VehicleTrackFrame` (a vehicle's fused
//! tracks; 1 and 2: the custody epoch).

mod columns;
pub(crate) mod detection;
mod fields;
mod frame_error;
pub(crate) mod header;
mod keys;
mod pack;
mod reasons;
mod rejection;
mod status;
mod tracks;
mod value;
mod vehicle_tracks;

pub use detection::{
    check_known_classes, decode_detection_frame, encode_detection_frame, BoxColumns, Detection,
    DetectionFrame,
};
pub use fields::{
    is_name, INT64_MAX, MAX_CLASSES, MAX_CLASS_NAME, MAX_FRAME_ID, MAX_NOTICE_SEQS, NAME_PATTERN,
};
pub use frame_error::{decode_frame_error, encode_frame_error, FrameError};
pub use header::{
    DecodeLimits, MAX_COORDINATE_M, MAX_SIZE_M, MAX_SPEED_MPS, MAX_YAW_RAD, POSE_TOLERANCE,
};
pub use keys::{Keys, DEFAULT_PREFIX, VEHICLE_STREAM};
pub use reasons::{
    ErrorReason, SensorCondition, TrackState, DETECTION_SCHEMA_VERSION, SCHEMA_VERSION,
    STATUS_SCHEMA_VERSION, TRACK_EPOCH_SCHEMA_VERSION, TRACK_SCHEMA_VERSION,
    VEHICLE_TRACK_SCHEMA_VERSION,
};
pub use rejection::Rejection;
pub use status::{
    decode_service_status, FusedSensorStatus, SensorStatus, ServiceStatus, VehicleStatus,
    MAX_FUSED_SENSORS,
};
pub use tracks::{covariance_at, decode_track_frame, encode_track_frame, TrackColumns, TrackFrame};
pub use vehicle_tracks::{
    decode_vehicle_track_frame, encode_vehicle_track_frame, VehicleTrackFrame, NEVER_UPDATED,
};

/// The Zenoh encoding of every message (Zenoh has no named constant for it).
pub const ENCODING: &str = "application/msgpack";

#[cfg(test)]
mod fusion_tests;
#[cfg(test)]
mod tests;
