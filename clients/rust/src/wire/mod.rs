//! The wire format, schema version 1 (schemas/README.md): typed messages, their msgpack
//! encoders (byte for byte the reference encoder's output) and validating decoders (the
//! reference decoder's verdicts: the same reason and field for the first failing check).

mod columns;
pub(crate) mod detection;
mod fields;
mod frame_error;
mod header;
mod keys;
mod pack;
mod reasons;
mod rejection;
mod status;
mod tracks;
mod value;

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
pub use keys::{Keys, DEFAULT_PREFIX};
pub use reasons::{ErrorReason, TrackState, SCHEMA_VERSION, TRACK_SCHEMA_VERSION};
pub use rejection::Rejection;
pub use status::{decode_service_status, SensorStatus, ServiceStatus};
pub use tracks::{covariance_at, decode_track_frame, encode_track_frame, TrackColumns, TrackFrame};

/// The Zenoh encoding of every message (Zenoh has no named constant for it).
pub const ENCODING: &str = "application/msgpack";

#[cfg(test)]
mod tests;
