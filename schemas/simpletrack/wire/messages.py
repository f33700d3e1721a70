"""Every wire message as a light frozen dataclass, and the field table each is validated with.

These are what the decoders return and what clients hold. The pydantic models of
``simpletrack.wire.models`` describe the same messages field for field (they generate the JSON
Schemas and are what the server builds); ``tests/wire/test_validator_agrees.py`` holds both
to the same verdicts. Column contents (lengths, finiteness, sizes) are the codec's business.
"""

from __future__ import annotations

from dataclasses import dataclass, fields
from dataclasses import field as dataclass_field  # FrameError has a field named "field"
from typing import Any

import numpy as np
import numpy.typing as npt

from simpletrack.wire import columns
from simpletrack.wire.columns import ColumnSpec
from simpletrack.wire.fields import (
    Field,
    MapSpec,
    all_floats,
    array,
    binary,
    boolean,
    integer,
    literal,
    nullable,
    number,
    one_of,
    string,
    strings_between,
)
from simpletrack.wire.reasons import (
    DETECTION_SCHEMA_VERSION,
    SCHEMA_VERSION,
    STATUS_SCHEMA_VERSION,
    TRACK_EPOCH_SCHEMA_VERSION,
    VEHICLE_TRACK_SCHEMA_VERSION,
    ErrorReason,
    SensorCondition,
)

# One Zenoh key chunk, also safe as a file name: no '/', wildcards, '@' or leading dot.
NAME_PATTERN = r"^[A-Za-z0-9_][A-Za-z0-9_.\-]{0,63}$"
# A snapshot's sensor: a sensor's name, or the fused vehicle's stream (keys.VEHICLE_STREAM),
# which is checkpointed and handed off under that name.
SNAPSHOT_SENSOR_PATTERN = r"^(?:@vehicle|[A-Za-z0-9_][A-Za-z0-9_.\-]{0,63})$"
# The most sensors one vehicle fuses (VehicleTrackFrame.sensors).
MAX_FUSED_SENSORS = 64
INT64_MAX = 2**63 - 1
INT32_MAX = 2**31 - 1
# The most frames one coalesced drop notice names (FrameError.seqs): ~9 KB of msgpack at most.
MAX_NOTICE_SEQS = 1024
# Field metadata of an optional field left out of the map when it is None, so that messages
# without it stay byte for byte what they were before it existed.
OMIT_NONE = {"omit_none": True}
# Field metadata of a field a message's version 2 added: left out of a version-1 message's
# map while empty (one that holds something stays, and its version's table refuses it).
SINCE_V2 = {"since": 2}


@dataclass(frozen=True, slots=True, kw_only=True)
class BoxColumns:
    """N detection boxes as columns (layout: ``simpletrack.wire.columns.DETECTION_COLUMNS``)."""

    count: int
    classes: list[str]
    class_index: bytes
    center: bytes
    size: bytes
    yaw: bytes
    score: bytes
    velocity: bytes | None = None


@dataclass(frozen=True, slots=True, kw_only=True)
class TrackColumns:
    """N tracks as columns (layout: ``simpletrack.wire.columns.TRACK_COLUMNS``)."""

    count: int
    classes: list[str]
    id: bytes
    class_index: bytes
    center: bytes
    size: bytes
    yaw: bytes
    score: bytes
    velocity: bytes
    state: bytes
    hits: bytes
    age: bytes
    time_since_update: bytes
    # Version 2 (absent, not nil, from a version-1 frame: its bytes stay what they were).
    covariance: bytes | None = dataclass_field(default=None, metadata=OMIT_NONE)
    age_s: bytes | None = dataclass_field(default=None, metadata=OMIT_NONE)
    time_since_update_s: bytes | None = dataclass_field(default=None, metadata=OMIT_NONE)


@dataclass(frozen=True, slots=True, kw_only=True)
class DetectionFrame:
    """One sensor frame of 3D detections: ``<prefix>/<vehicle>/<sensor>/detections``."""

    schema_version: int
    vehicle: str
    sensor: str
    seq: int
    stamp_ns: int
    frame_id: str
    pose: list[float] | None = None
    key_frame: bool = True
    session_id: int | None = None
    boxes: BoxColumns
    # Version 2: sensor -> vehicle, 4x4 row-major (absent from a version-1 frame).
    extrinsic: list[float] | None = dataclass_field(default=None, metadata=OMIT_NONE)

    def pose_matrix(self) -> npt.NDArray[np.float64] | None:
        return None if self.pose is None else np.asarray(self.pose, np.float64).reshape(4, 4)


@dataclass(frozen=True, slots=True, kw_only=True)
class TrackFrame:
    """The tracks after one detection frame: ``<prefix>/<vehicle>/<sensor>/tracks``."""

    schema_version: int
    vehicle: str
    sensor: str
    seq: int
    stamp_ns: int
    frame_id: str
    pose: list[float] | None = None
    key_frame: bool = True
    instance: str
    received_ns: int
    published_ns: int
    tracks: TrackColumns
    # Version 3: the stream's custody epoch (schemas/README.md, "Custody epoch"); absent
    # from an earlier version and from a version-3 frame that carries none.
    epoch: int | None = dataclass_field(default=None, metadata=OMIT_NONE)


@dataclass(frozen=True, slots=True, kw_only=True)
class VehicleTrackColumns(TrackColumns):
    """A vehicle's N fused tracks as columns (layout: ``columns.VEHICLE_TRACK_COLUMNS``):
    a TrackFrame version 2's, ``existence`` and ``sensor_stamp_ns`` (N x len(sensors))."""

    existence: bytes
    sensor_stamp_ns: bytes


@dataclass(frozen=True, slots=True, kw_only=True)
class VehicleTrackFrame:
    """A vehicle's fused tracks: ``<prefix>/<vehicle>/@vehicle/tracks``. ``seq`` counts the
    vehicle stream's messages; ``stamp_ns`` is the time every box is at: the stamp of the
    input frame (``sensor``, ``sensor_seq``) that produced the message."""

    schema_version: int
    vehicle: str
    seq: int
    stamp_ns: int
    sensor: str
    sensor_seq: int
    frame_id: str
    pose: list[float] | None = None
    instance: str
    received_ns: int
    published_ns: int
    sensors: list[str]
    sensor_state: list[SensorCondition]
    tracks: VehicleTrackColumns
    # Version 2: the stream's custody epoch, as a TrackFrame's (absent from version 1).
    epoch: int | None = dataclass_field(default=None, metadata=OMIT_NONE)

    def pose_matrix(self) -> npt.NDArray[np.float64] | None:
        return None if self.pose is None else np.asarray(self.pose, np.float64).reshape(4, 4)


@dataclass(frozen=True, slots=True, kw_only=True)
class FrameError:
    """A frame that was not tracked: ``<prefix>/<vehicle>/<sensor>/errors``."""

    schema_version: int
    vehicle: str
    sensor: str
    seq: int | None = None
    stamp_ns: int | None = None
    reason: ErrorReason
    field: str | None = None
    detail: str
    instance: str
    received_ns: int
    # A drop notice: the seq of every frame it stands for (None where unreadable), in order.
    seqs: list[int | None] | None = dataclass_field(default=None, metadata=OMIT_NONE)


@dataclass(frozen=True, slots=True, kw_only=True)
class SensorStatus:
    vehicle: str
    sensor: str
    last_seq: int | None
    last_stamp_ns: int | None
    frames: int
    active_tracks: int
    idle_s: float
    rate_hz: float = 0.0
    resets: int = 0
    implausible_frames: int = 0


@dataclass(frozen=True, slots=True, kw_only=True)
class FusedSensorStatus:
    """One sensor of a fused vehicle, as the vehicle's tracker sees it."""

    sensor: str
    state: SensorCondition
    last_seq: int | None
    last_stamp_ns: int | None
    frames: int
    idle_s: float | None
    latency_s: float | None  # median stamp -> receipt over recent frames
    clock_offset_s: float | None
    offset_m: list[float] | None  # x, y of its detections from the vehicle's tracks
    flagged_frames: int
    detail: str = ""  # why it is flagged


@dataclass(frozen=True, slots=True, kw_only=True)
class VehicleStatus:
    """A fused vehicle: one tracker fed by its sensors (ServiceStatus version 2)."""

    vehicle: str
    seq: int | None  # of its last VehicleTrackFrame
    last_stamp_ns: int | None
    active_tracks: int
    frames: int  # input frames applied
    late_frames: int
    reprocessed_frames: int
    sensors: list[FusedSensorStatus]


@dataclass(frozen=True, slots=True, kw_only=True)
class ServiceStatus:
    """Reply of the status queryable ``<prefix>/@simpletrack/<instance>/status``."""

    schema_version: int
    instance: str
    version: str
    preset: str
    classes: list[str]
    config_digest: str
    started_ns: int
    ready: bool
    queue_depth: int
    sensors: list[SensorStatus]
    members: list[str] = dataclass_field(default_factory=list)
    standby_sensors: int = 0
    handoffs_in: int = 0
    handoffs_out: int = 0
    failovers: int = 0
    # Version 2 (an empty list from a version-1 status).
    vehicles: list[VehicleStatus] = dataclass_field(default_factory=list, metadata=SINCE_V2)


@dataclass(frozen=True, slots=True, kw_only=True)
class SensorSnapshot:
    """One sensor's tracker state: the snapshot file, and the snapshot queryable's reply."""

    schema_version: int
    vehicle: str
    sensor: str
    last_seq: int | None = None
    last_stamp_ns: int | None = None
    stamp_origin_ns: int | None = None
    id_base: int = 0
    id_next: int = 0
    frames: int = 0
    last_received_ns: int | None = None
    last_session_id: int | None = None
    config_digest: str
    tracker: bytes | None = None
    written_ns: int
    epoch: int | None = None


# --- the field tables (order = the order of checks, as in schemas/README.md) ---------------

_name = string(pattern=NAME_PATTERN)
_int64 = integer(0, INT64_MAX)
_float = nullable(number)
_pose = nullable(array(number, min_length=16, max_length=16, fast=all_floats))
_classes = array(string(min_length=1, max_length=64), max_length=1024, fast=strings_between(1, 64))
_count = integer(0, INT32_MAX)


def _columns(names: tuple[str, ...], optional: tuple[str, ...] = ()) -> list[Field]:
    return [Field(n, nullable(binary), None) if n in optional else Field(n, binary) for n in names]


def _header(version: int = SCHEMA_VERSION) -> list[Field]:
    return [
        Field("schema_version", literal(version)),
        Field("vehicle", _name),
        Field("sensor", _name),
        Field("seq", _int64),
        Field("stamp_ns", _int64),
    ]


BOX_COLUMNS = MapSpec(
    "BoxColumns",
    BoxColumns,
    [
        Field("count", _count),
        Field("classes", _classes),
        *_columns(
            ("class_index", "center", "size", "yaw", "score", "velocity"), optional=("velocity",)
        ),
    ],
)


def _track_columns(specs: tuple[ColumnSpec, ...]) -> list[Field]:
    """A TrackFrame version's column fields, from columns.py's layouts (one list of names)."""
    return _columns(tuple(c.name for c in specs), tuple(c.name for c in specs if c.optional))


TRACK_COLUMNS_V1 = MapSpec(
    "TrackColumnsV1",
    TrackColumns,
    [
        Field("count", _count),
        Field("classes", _classes),
        *_track_columns(columns.TRACK_COLUMNS_V1),
    ],
)
TRACK_COLUMNS = MapSpec(
    "TrackColumns",
    TrackColumns,
    [Field("count", _count), Field("classes", _classes), *_track_columns(columns.TRACK_COLUMNS)],
)


def _detection_frame(name: str, version: int, added: list[Field]) -> MapSpec[DetectionFrame]:
    return MapSpec(
        name,
        DetectionFrame,
        [
            *_header(version),
            Field("frame_id", string(min_length=1, max_length=128)),
            Field("pose", _pose, None),
            Field("key_frame", boolean, True),
            Field("session_id", nullable(_int64), None),
            Field("boxes", BOX_COLUMNS),
            *added,
        ],
    )


# Named as the pydantic models are (models.DetectionFrameV1 is version 1).
DETECTION_FRAME_V1 = _detection_frame("DetectionFrameV1", 1, [])
DETECTION_FRAME = _detection_frame(
    "DetectionFrame", DETECTION_SCHEMA_VERSION, [Field("extrinsic", _pose, None)]
)
# Each DetectionFrame version a decoder reads (a version-1 frame holding an extrinsic is an
# extra_field, as it is to a version-1 reader).
DETECTION_FRAMES: dict[int, MapSpec[DetectionFrame]] = {1: DETECTION_FRAME_V1, 2: DETECTION_FRAME}


# The custody epoch of a tracks stream (TrackFrame version 3, VehicleTrackFrame version 2).
_EPOCH = Field("epoch", nullable(_int64), None)


def _track_frame(
    name: str, version: int, columns: MapSpec[TrackColumns], added: tuple[Field, ...] = ()
) -> MapSpec[TrackFrame]:
    return MapSpec(
        name,
        TrackFrame,
        [
            *_header(version),
            Field("frame_id", string(min_length=1, max_length=128)),
            Field("pose", _pose, None),
            Field("key_frame", boolean, True),
            Field("instance", _name),
            Field("received_ns", _int64),
            Field("published_ns", _int64),
            Field("tracks", columns),
            *added,
        ],
    )


# Named as the pydantic models are (models.TrackFrameV1, TrackFrameV2), whose messages these
# repeat.
TRACK_FRAME_V1 = _track_frame("TrackFrameV1", 1, TRACK_COLUMNS_V1)
TRACK_FRAME_V2 = _track_frame("TrackFrameV2", 2, TRACK_COLUMNS)
TRACK_FRAME = _track_frame("TrackFrame", TRACK_EPOCH_SCHEMA_VERSION, TRACK_COLUMNS, (_EPOCH,))
# Each TrackFrame version a decoder reads, with its fields (a version-1 frame holding a
# version-2 column, or a version-2 one holding an epoch, is an extra_field, as it is to a
# reader of that version).
TRACK_FRAMES: dict[int, MapSpec[TrackFrame]] = {
    1: TRACK_FRAME_V1,
    2: TRACK_FRAME_V2,
    3: TRACK_FRAME,
}
VEHICLE_TRACK_COLUMNS = MapSpec(
    "VehicleTrackColumns",
    VehicleTrackColumns,
    [
        Field("count", _count),
        Field("classes", _classes),
        *_track_columns(columns.VEHICLE_TRACK_COLUMNS),
    ],
)


# Rules across fields (sensors unique, one state per sensor, sensor among them) and the
# columns' contents are the codec's (codec.decode_vehicle_track_frame).
def _vehicle_track_frame(
    name: str, version: int, added: tuple[Field, ...] = ()
) -> MapSpec[VehicleTrackFrame]:
    return MapSpec(
        name,
        VehicleTrackFrame,
        [
            Field("schema_version", literal(version)),
            Field("vehicle", _name),
            Field("seq", _int64),
            Field("stamp_ns", _int64),
            Field("sensor", _name),
            Field("sensor_seq", _int64),
            Field("frame_id", string(min_length=1, max_length=128)),
            Field("pose", _pose, None),
            Field("instance", _name),
            Field("received_ns", _int64),
            Field("published_ns", _int64),
            Field("sensors", array(_name, min_length=1, max_length=MAX_FUSED_SENSORS)),
            Field("sensor_state", array(one_of(SensorCondition), max_length=MAX_FUSED_SENSORS)),
            Field("tracks", VEHICLE_TRACK_COLUMNS),
            *added,
        ],
    )


VEHICLE_TRACK_FRAME_V1 = _vehicle_track_frame("VehicleTrackFrameV1", 1)
VEHICLE_TRACK_FRAME = _vehicle_track_frame(
    "VehicleTrackFrame", VEHICLE_TRACK_SCHEMA_VERSION, (_EPOCH,)
)
VEHICLE_TRACK_FRAMES: dict[int, MapSpec[VehicleTrackFrame]] = {
    1: VEHICLE_TRACK_FRAME_V1,
    2: VEHICLE_TRACK_FRAME,
}
FRAME_ERROR = MapSpec(
    "FrameError",
    FrameError,
    [
        Field("schema_version", literal(SCHEMA_VERSION)),
        Field("vehicle", _name),
        Field("sensor", _name),
        Field("seq", nullable(_int64), None),
        Field("stamp_ns", nullable(_int64), None),
        Field("reason", one_of(ErrorReason)),
        Field("field", nullable(string(max_length=256)), None),
        Field("detail", string(max_length=1024)),
        Field("instance", _name),
        Field("received_ns", _int64),
        Field("seqs", nullable(array(nullable(_int64), max_length=MAX_NOTICE_SEQS)), None),
    ],
)
SENSOR_STATUS = MapSpec(
    "SensorStatus",
    SensorStatus,
    [
        Field("vehicle", _name),
        Field("sensor", _name),
        Field("last_seq", nullable(_int64)),
        Field("last_stamp_ns", nullable(_int64)),
        Field("frames", _int64),
        Field("active_tracks", _int64),
        Field("idle_s", number),
        Field("rate_hz", number, 0.0),
        Field("resets", _int64, 0),
        Field("implausible_frames", _int64, 0),
    ],
)
FUSED_SENSOR_STATUS = MapSpec(
    "FusedSensorStatus",
    FusedSensorStatus,
    [
        Field("sensor", _name),
        Field("state", one_of(SensorCondition)),
        Field("last_seq", nullable(_int64)),
        Field("last_stamp_ns", nullable(_int64)),
        Field("frames", _int64),
        Field("idle_s", _float),
        Field("latency_s", _float),
        Field("clock_offset_s", _float),
        Field("offset_m", nullable(array(number, min_length=2, max_length=2, fast=all_floats))),
        Field("flagged_frames", _int64),
        Field("detail", string(max_length=256), ""),
    ],
)
VEHICLE_STATUS = MapSpec(
    "VehicleStatus",
    VehicleStatus,
    [
        Field("vehicle", _name),
        Field("seq", nullable(_int64)),
        Field("last_stamp_ns", nullable(_int64)),
        Field("active_tracks", _int64),
        Field("frames", _int64),
        Field("late_frames", _int64),
        Field("reprocessed_frames", _int64),
        Field("sensors", array(FUSED_SENSOR_STATUS, max_length=MAX_FUSED_SENSORS)),
    ],
)


def _service_status(name: str, version: int, added: list[Field]) -> MapSpec[ServiceStatus]:
    return MapSpec(
        name,
        ServiceStatus,
        [
            Field("schema_version", literal(version)),
            Field("instance", _name),
            Field("version", string()),
            Field("preset", string()),
            Field("classes", array(string())),
            Field("config_digest", string()),
            Field("started_ns", _int64),
            Field("ready", boolean),
            Field("queue_depth", _int64),
            Field("sensors", array(SENSOR_STATUS)),
            Field("members", array(_name), []),
            Field("standby_sensors", _int64, 0),
            Field("handoffs_in", _int64, 0),
            Field("handoffs_out", _int64, 0),
            Field("failovers", _int64, 0),
            *added,
        ],
    )


# Named as the pydantic models are (models.ServiceStatusV1 is version 1).
SERVICE_STATUS_V1 = _service_status("ServiceStatusV1", 1, [])
SERVICE_STATUS = _service_status(
    "ServiceStatus", STATUS_SCHEMA_VERSION, [Field("vehicles", array(VEHICLE_STATUS), [])]
)
SENSOR_SNAPSHOT = MapSpec(
    "SensorSnapshot",
    SensorSnapshot,
    [
        Field("schema_version", literal(SCHEMA_VERSION)),
        Field("vehicle", _name),
        Field("sensor", string(pattern=SNAPSHOT_SENSOR_PATTERN)),
        Field("last_seq", nullable(_int64), None),
        Field("last_stamp_ns", nullable(_int64), None),
        Field("stamp_origin_ns", nullable(_int64), None),
        Field("id_base", _int64, 0),
        Field("id_next", _int64, 0),
        Field("frames", _int64, 0),
        Field("last_received_ns", nullable(_int64), None),
        Field("last_session_id", nullable(_int64), None),
        Field("config_digest", string()),
        Field("tracker", nullable(binary), None),
        Field("written_ns", _int64),
        Field("epoch", nullable(_int64), None),
    ],
)

Message = (
    DetectionFrame
    | TrackFrame
    | VehicleTrackFrame
    | FrameError
    | ServiceStatus
    | SensorSnapshot
    | SensorStatus
    | VehicleStatus
    | FusedSensorStatus
    | BoxColumns
    | TrackColumns
)
MESSAGE_TYPES = (
    DetectionFrame,
    TrackFrame,
    VehicleTrackFrame,
    FrameError,
    ServiceStatus,
    SensorSnapshot,
    SensorStatus,
    VehicleStatus,
    FusedSensorStatus,
    BoxColumns,
    TrackColumns,  # VehicleTrackColumns too, a subclass
)

# By the name of each message's pydantic model; a previous version's as its model is named
# (models.TrackFrameV1, ...).
SPECS: dict[str, MapSpec[Any]] = {
    s.name: s
    for s in (
        BOX_COLUMNS,
        TRACK_COLUMNS,
        TRACK_COLUMNS_V1,
        VEHICLE_TRACK_COLUMNS,
        DETECTION_FRAME,
        DETECTION_FRAME_V1,
        TRACK_FRAME,
        TRACK_FRAME_V2,
        TRACK_FRAME_V1,
        VEHICLE_TRACK_FRAME,
        VEHICLE_TRACK_FRAME_V1,
        FRAME_ERROR,
        SENSOR_STATUS,
        FUSED_SENSOR_STATUS,
        VEHICLE_STATUS,
        SERVICE_STATUS,
        SERVICE_STATUS_V1,
        SENSOR_SNAPSHOT,
    )
}
# The tables of each message read in several versions, by version.
VERSIONS: dict[str, dict[int, MapSpec[Any]]] = {
    "DetectionFrame": dict(DETECTION_FRAMES),
    "TrackFrame": dict(TRACK_FRAMES),
    "VehicleTrackFrame": dict(VEHICLE_TRACK_FRAMES),
    "ServiceStatus": {1: SERVICE_STATUS_V1, 2: SERVICE_STATUS},
}


def spec_of(message: Message) -> MapSpec[Any]:
    """The field table a message is validated with (by its version, for a message read in
    several)."""
    name = type(message).__name__
    versions = VERSIONS.get(name)
    if versions is not None:
        return versions.get(getattr(message, "schema_version", 0), SPECS[name])
    return SPECS[name]


def to_map(message: Message) -> dict[str, Any]:
    """A message as the map that travels: fields in declaration order, nested messages as
    maps (what ``pydantic``'s ``model_dump(mode="python")`` gives for the model twin)."""
    version = getattr(message, "schema_version", None)
    out = {}
    for f in fields(message):
        value = _plain(getattr(message, f.name))
        if value is None and f.metadata.get("omit_none"):
            continue
        since = f.metadata.get("since")
        if since is not None and version is not None and version < since and not value:
            continue
        out[f.name] = value
    return out


def _plain(value: Any) -> Any:
    if isinstance(value, MESSAGE_TYPES):
        return to_map(value)
    if type(value) is list:
        return [_plain(v) for v in value]
    return value
