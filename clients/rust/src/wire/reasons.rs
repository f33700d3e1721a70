//! Enumerations that travel on the wire: error reasons and track states.

use std::fmt;

/// The schema version this crate reads and writes (`schema_version`).
pub const SCHEMA_VERSION: u64 = 1;
/// `TrackFrame` version 2 added covariance and ages in seconds; what a service sends unless
/// told otherwise (its `tracks_schema_version`).
pub const TRACK_SCHEMA_VERSION: u64 = 2;
/// `TrackFrame` version 3 adds the optional custody `epoch`; the decoder reads 1 to 3.
pub const TRACK_EPOCH_SCHEMA_VERSION: u64 = 3;
/// `DetectionFrame` version 2 adds the optional `extrinsic`; the decoder reads 1 and 2, the
/// encoder writes 2 only for a frame with an extrinsic.
pub const DETECTION_SCHEMA_VERSION: u64 = 2;
/// `ServiceStatus` version 2 adds the fused vehicles; the decoder reads 1 and 2.
pub const STATUS_SCHEMA_VERSION: u64 = 2;
/// `VehicleTrackFrame`, a message of its own: version 2 adds the optional custody `epoch`.
/// The decoder reads 1 and 2; the encoder writes 2 only for a frame with an epoch.
pub const VEHICLE_TRACK_SCHEMA_VERSION: u64 = 2;

/// Why a frame was not tracked (a `FrameError`'s `reason`), or why a decoder refused a payload.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum ErrorReason {
    TooLarge,
    Malformed,
    WrongVersion,
    MissingField,
    ExtraField,
    WrongType,
    InvalidValue,
    ColumnLength,
    NonFinite,
    NonPositiveSize,
    UnknownClass,
    KeyMismatch,
    OutOfOrder,
    SeqNotIncreasing,
    DuplicateSeq,
    TooManySensors,
    /// A fused sensor's frame older than the vehicle's re-processing history.
    Late,
    /// A fused sensor flagged for its clock or extrinsic: its frames are kept out.
    SensorFlagged,
    DroppedQueueFull,
    DroppedShutdown,
    Missed,
    InternalError,
}

impl ErrorReason {
    pub const ALL: [ErrorReason; 22] = [
        Self::TooLarge,
        Self::Malformed,
        Self::WrongVersion,
        Self::MissingField,
        Self::ExtraField,
        Self::WrongType,
        Self::InvalidValue,
        Self::ColumnLength,
        Self::NonFinite,
        Self::NonPositiveSize,
        Self::UnknownClass,
        Self::KeyMismatch,
        Self::OutOfOrder,
        Self::SeqNotIncreasing,
        Self::DuplicateSeq,
        Self::TooManySensors,
        Self::Late,
        Self::SensorFlagged,
        Self::DroppedQueueFull,
        Self::DroppedShutdown,
        Self::Missed,
        Self::InternalError,
    ];

    /// The string that travels.
    pub fn as_str(self) -> &'static str {
        match self {
            Self::TooLarge => "too_large",
            Self::Malformed => "malformed",
            Self::WrongVersion => "wrong_version",
            Self::MissingField => "missing_field",
            Self::ExtraField => "extra_field",
            Self::WrongType => "wrong_type",
            Self::InvalidValue => "invalid_value",
            Self::ColumnLength => "column_length",
            Self::NonFinite => "non_finite",
            Self::NonPositiveSize => "non_positive_size",
            Self::UnknownClass => "unknown_class",
            Self::KeyMismatch => "key_mismatch",
            Self::OutOfOrder => "out_of_order",
            Self::SeqNotIncreasing => "seq_not_increasing",
            Self::DuplicateSeq => "duplicate_seq",
            Self::TooManySensors => "too_many_sensors",
            Self::Late => "late",
            Self::SensorFlagged => "sensor_flagged",
            Self::DroppedQueueFull => "dropped_queue_full",
            Self::DroppedShutdown => "dropped_shutdown",
            Self::Missed => "missed",
            Self::InternalError => "internal_error",
        }
    }

    pub fn parse(s: &str) -> Option<Self> {
        Self::ALL.into_iter().find(|r| r.as_str() == s)
    }

    /// Frames shed or lost rather than refused: the data was fine, nobody tracked it.
    pub fn is_drop(self) -> bool {
        matches!(
            self,
            Self::DroppedQueueFull | Self::DroppedShutdown | Self::Missed
        )
    }
}

impl fmt::Display for ErrorReason {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.as_str())
    }
}

/// Codes of `TrackFrame.tracks.state`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum TrackState {
    /// Fewer than the preset's `min_hits` hits so far.
    Tentative = 0,
    /// Confirmed and updated on this frame.
    Confirmed = 1,
    /// Confirmed, not updated on this frame (`time_since_update > 0`).
    Coasting = 2,
}

impl TrackState {
    pub fn from_code(code: i32) -> Option<Self> {
        match code {
            0 => Some(Self::Tentative),
            1 => Some(Self::Confirmed),
            2 => Some(Self::Coasting),
            _ => None,
        }
    }
}

/// A fused sensor's condition (`VehicleTrackFrame::sensor_state`, `FusedSensorStatus::state`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum SensorCondition {
    Ok,
    /// Not yet verified against the others: updates tracks, starts none.
    Probation,
    /// No frame for a while.
    Silent,
    /// Its stamps are off: its frames are kept out.
    Clock,
    /// Its detections are offset from the vehicle's tracks: kept out.
    Extrinsic,
    /// Configured, never heard.
    Unseen,
}

impl SensorCondition {
    pub const ALL: [SensorCondition; 6] = [
        Self::Ok,
        Self::Probation,
        Self::Silent,
        Self::Clock,
        Self::Extrinsic,
        Self::Unseen,
    ];

    /// The string that travels.
    pub fn as_str(self) -> &'static str {
        match self {
            Self::Ok => "ok",
            Self::Probation => "probation",
            Self::Silent => "silent",
            Self::Clock => "clock",
            Self::Extrinsic => "extrinsic",
            Self::Unseen => "unseen",
        }
    }

    pub fn parse(s: &str) -> Option<Self> {
        Self::ALL.into_iter().find(|c| c.as_str() == s)
    }
}

impl fmt::Display for SensorCondition {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.as_str())
    }
}
