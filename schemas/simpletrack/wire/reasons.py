"""Enumerations that travel on the wire: error reasons and track states."""

from __future__ import annotations

from enum import IntEnum, StrEnum
from typing import Final

SCHEMA_VERSION: Final = 1
# TrackFrame version 2 added covariance and ages in seconds, version 3 the custody epoch.
# Decoders read 1 to 3; a service sends the one its setting tracks_schema_version names,
# by default TRACK_SCHEMA_VERSION: until every reader decodes 3, a version a reader of
# before the epoch takes (schemas/README.md, Versioning).
TRACK_SCHEMA_VERSION: Final = 2
TRACK_EPOCH_SCHEMA_VERSION: Final = 3
TRACK_SCHEMA_VERSIONS: Final = (1, 2, 3)
# DetectionFrame version 2 adds the optional extrinsic. Encoders write 2 only when they send
# one, so a frame without it is byte for byte what a version-1 publisher sent.
DETECTION_SCHEMA_VERSION: Final = 2
DETECTION_SCHEMA_VERSIONS: Final = (1, 2)
# ServiceStatus version 2 adds the fused vehicles; decoders read 1 and 2.
STATUS_SCHEMA_VERSION: Final = 2
STATUS_SCHEMA_VERSIONS: Final = (1, 2)
# VehicleTrackFrame is a message of its own; its version 2 adds the custody epoch. Encoders
# write 2 only when they send one, so a frame without it is byte for byte a version-1 frame.
VEHICLE_TRACK_SCHEMA_VERSION: Final = 2
VEHICLE_TRACK_SCHEMA_VERSIONS: Final = (1, 2)


class ErrorReason(StrEnum):
    """Why a detection frame was not tracked. The string value is what travels."""

    # Decoding and validation of the payload (simpletrack.wire.codec).
    TOO_LARGE = "too_large"  # payload bytes or box count over the configured cap
    MALFORMED = "malformed"  # not msgpack, not a map, trailing bytes, bad UTF-8
    WRONG_VERSION = "wrong_version"
    MISSING_FIELD = "missing_field"
    EXTRA_FIELD = "extra_field"
    WRONG_TYPE = "wrong_type"
    INVALID_VALUE = "invalid_value"  # e.g. bad id characters, class_index out of the table
    COLUMN_LENGTH = "column_length"  # a column's byte length disagrees with boxes.count
    NON_FINITE = "non_finite"  # NaN or inf in a float column or the pose
    NON_POSITIVE_SIZE = "non_positive_size"
    UNKNOWN_CLASS = "unknown_class"  # a class name the tracker configuration does not know
    # Routing and per-sensor ordering (service).
    KEY_MISMATCH = "key_mismatch"  # vehicle/sensor in the payload differ from the key
    OUT_OF_ORDER = "out_of_order"  # stamp_ns not after the sensor's last processed stamp
    SEQ_NOT_INCREASING = "seq_not_increasing"
    DUPLICATE_SEQ = "duplicate_seq"  # same seq as the last processed frame: ignored
    TOO_MANY_SENSORS = "too_many_sensors"
    # Vehicle fusion (docs/SERVICE.md, "Vehicle fusion"): a fused sensor's frame kept out of
    # the vehicle's tracks.
    LATE = "late"  # older than the vehicle's re-processing history: cannot be applied in order
    SENSOR_FLAGGED = "sensor_flagged"  # the sensor's clock or extrinsic is off; detail says which
    # Load shedding: the frame was valid as far as anyone looked, but not processed.
    DROPPED_QUEUE_FULL = "dropped_queue_full"  # backpressure drop_oldest: the oldest goes
    DROPPED_SHUTDOWN = "dropped_shutdown"  # arrived after intake stopped, or drain timed out
    # Lost in transport (a router outage longer than the publisher's cache): never received.
    MISSED = "missed"
    INTERNAL_ERROR = "internal_error"  # a bug: reported rather than crashing the worker


DROP_REASONS = frozenset(
    {ErrorReason.DROPPED_QUEUE_FULL, ErrorReason.DROPPED_SHUTDOWN, ErrorReason.MISSED}
)


class SensorCondition(StrEnum):
    """A fused sensor's condition, as a vehicle's track frames and the status report it
    (``VehicleTrackFrame.sensor_state``, ``FusedSensorStatus.state``)."""

    OK = "ok"
    PROBATION = "probation"  # not yet verified against the others: updates tracks, starts none
    SILENT = "silent"  # no frame for a while
    CLOCK = "clock"  # its stamps are off: its frames are kept out
    EXTRINSIC = "extrinsic"  # its detections are offset from the vehicle's tracks: kept out
    UNSEEN = "unseen"  # configured, never heard


class WireTrackState(IntEnum):
    """Track state codes in ``TrackFrame.tracks.state``."""

    TENTATIVE = 0  # fewer than min_hits hits so far
    CONFIRMED = 1  # confirmed and updated on this frame
    COASTING = 2  # confirmed, but not updated on this frame (time_since_update > 0)


# Each state code's name as text (JSON lines, the view, Foxglove's rows): "tentative", ...
STATE_NAMES: dict[int, str] = {int(s): s.name.lower() for s in WireTrackState}
