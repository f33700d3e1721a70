"""Pydantic models of every wire message: the source of the JSON Schemas in ``schemas/json``
and what the server builds its messages from. Decoders do not use them: they validate with the
field tables of ``simpletrack.wire.messages`` (no pydantic), which agree with these models
verdict for verdict (``tests/wire/test_validator_agrees.py``). The column contents (lengths,
finiteness, sizes) are checked by ``simpletrack.wire.codec``.

All messages are msgpack maps with string keys. Optional fields may be absent or nil.
Unknown keys are rejected (``extra_field``) so that typos never pass silently.
"""

from __future__ import annotations

from typing import Annotated, Any, Literal

import numpy as np
import numpy.typing as npt
from pydantic import BaseModel, ConfigDict, Field, SerializerFunctionWrapHandler, model_serializer

from simpletrack.wire.columns import (
    DETECTION_SPECS,
    TRACK_SPECS,
    VEHICLE_TRACK_SPECS,
    BoxArrays,
    ColumnSpec,
    to_column,
)
from simpletrack.wire.messages import MAX_FUSED_SENSORS, MAX_NOTICE_SEQS, SNAPSHOT_SENSOR_PATTERN
from simpletrack.wire.messages import NAME_PATTERN as NAME_PATTERN  # the server's import
from simpletrack.wire.reasons import SCHEMA_VERSION, ErrorReason, SensorCondition

Name = Annotated[str, Field(pattern=NAME_PATTERN, description="letters, digits, _ . - (<= 64)")]
Int64 = Annotated[int, Field(ge=0, le=2**63 - 1)]
ClassName = Annotated[str, Field(min_length=1, max_length=64)]
Pose = Annotated[
    list[float],
    Field(
        min_length=16,
        max_length=16,
        description="4x4 rigid transform sensor->world, row-major, float64",
    ),
]
Extrinsic = Annotated[
    list[float],
    Field(
        min_length=16,
        max_length=16,
        description="4x4 rigid transform sensor->vehicle, row-major, float64",
    ),
]
# Not strict, as FrameError.reason: the wire carries the value's string.
Condition = Annotated[SensorCondition, Field(strict=False)]


def _column(spec: ColumnSpec, doc: str) -> Any:
    default: Any = None if spec.optional else ...
    return Field(default=default, description=doc, json_schema_extra=spec.json_schema_extra())


class WireModel(BaseModel):
    model_config = ConfigDict(strict=True, extra="forbid", frozen=True)


class BoxColumns(WireModel):
    """N detection boxes as columns. Box centre (not bottom), z up, yaw about +z from +x."""

    count: Annotated[int, Field(ge=0, le=2**31 - 1)] = Field(description="N, rows per column")
    classes: Annotated[list[ClassName], Field(max_length=1024)] = Field(
        description="class table of this frame; class_index points into it"
    )
    class_index: bytes = _column(DETECTION_SPECS["class_index"], "int32 index into classes")
    center: bytes = _column(DETECTION_SPECS["center"], "float32 x, y, z in metres")
    size: bytes = _column(DETECTION_SPECS["size"], "float32 l, w, h in metres, all > 0")
    yaw: bytes = _column(DETECTION_SPECS["yaw"], "float32 radians about +z")
    score: bytes = _column(DETECTION_SPECS["score"], "float64 detector confidence")
    velocity: bytes | None = _column(DETECTION_SPECS["velocity"], "float32 vx, vy in m/s")

    @classmethod
    def from_arrays(
        cls,
        classes: list[str] | tuple[str, ...],
        class_index: npt.ArrayLike,
        center: npt.ArrayLike,
        size: npt.ArrayLike,
        yaw: npt.ArrayLike,
        score: npt.ArrayLike,
        velocity: npt.ArrayLike | None = None,
    ) -> BoxColumns:
        s = DETECTION_SPECS
        ci = to_column(class_index, s["class_index"])
        return cls(
            count=len(ci) // 4,
            classes=list(classes),
            class_index=ci,
            center=to_column(center, s["center"]),
            size=to_column(size, s["size"]),
            yaw=to_column(yaw, s["yaw"]),
            score=to_column(score, s["score"]),
            velocity=None if velocity is None else to_column(velocity, s["velocity"]),
        )

    @classmethod
    def from_box_arrays(cls, boxes: BoxArrays) -> BoxColumns:
        return cls.from_arrays(
            boxes.classes,
            boxes.class_index,
            boxes.center,
            boxes.size,
            boxes.yaw,
            boxes.score,
            boxes.velocity,
        )


class TrackColumnsV1(WireModel):
    """N tracks as columns (TrackFrame version 1); same box convention as ``BoxColumns``."""

    count: Annotated[int, Field(ge=0, le=2**31 - 1)] = Field(description="N, rows per column")
    classes: Annotated[list[ClassName], Field(max_length=1024)] = Field(
        description="the service's class table (its tracker configuration's classes)"
    )
    id: bytes = _column(TRACK_SPECS["id"], "int64 track id, unique per sensor, never reused")
    class_index: bytes = _column(TRACK_SPECS["class_index"], "int32 index into classes")
    center: bytes = _column(TRACK_SPECS["center"], "float32 x, y, z in metres")
    size: bytes = _column(TRACK_SPECS["size"], "float32 l, w, h in metres")
    yaw: bytes = _column(TRACK_SPECS["yaw"], "float32 radians about +z")
    score: bytes = _column(TRACK_SPECS["score"], "float64 track score")
    velocity: bytes = _column(TRACK_SPECS["velocity"], "float32 vx, vy, vz in m/s")
    state: bytes = _column(TRACK_SPECS["state"], "int32 0 tentative, 1 confirmed, 2 coasting")
    hits: bytes = _column(TRACK_SPECS["hits"], "int32 frames with a detection update")
    age: bytes = _column(TRACK_SPECS["age"], "int32 frames since birth")
    time_since_update: bytes = _column(
        TRACK_SPECS["time_since_update"], "int32 frames since the last update"
    )


class TrackColumns(TrackColumnsV1):
    """N tracks as columns (TrackFrame version 2): version 1's and three more."""

    covariance: bytes | None = _column(
        TRACK_SPECS["covariance"],
        "float32 upper triangle, row-major, of the 6x6 covariance over x, y, z, vx, vy, vz "
        "(m^2, m^2/s, m^2/s^2); absent when the motion model keeps none",
    )
    age_s: bytes = _column(TRACK_SPECS["age_s"], "float64 seconds from birth to stamp_ns")
    time_since_update_s: bytes = _column(
        TRACK_SPECS["time_since_update_s"], "float64 seconds from the last update to stamp_ns"
    )

    @model_serializer(mode="wrap")
    def _omit_absent_covariance(self, handler: SerializerFunctionWrapHandler) -> dict[str, Any]:
        # Absent rather than nil, as the service sends it (simpletrack.wire.messages.OMIT_NONE).
        out: dict[str, Any] = handler(self)
        if out.get("covariance", 0) is None:
            del out["covariance"]
        return out


class _Header(WireModel):
    schema_version: Literal[1] = Field(description=f"always {SCHEMA_VERSION} for this layout")
    vehicle: Name
    sensor: Name
    seq: Int64 = Field(description="per-sensor sequence number, strictly increasing")
    stamp_ns: Int64 = Field(description="sensor time of the frame, nanoseconds")


class DetectionFrameV1(_Header):
    """One sensor frame of 3D detections: ``<prefix>/<vehicle>/<sensor>/detections``
    (version 1, what a publisher without an extrinsic sends)."""

    frame_id: Annotated[str, Field(min_length=1, max_length=128)] = Field(
        description="name of the coordinate frame the boxes are expressed in"
    )
    pose: Pose | None = Field(default=None, description="optional sensor->world 4x4, row-major")
    key_frame: bool = Field(default=True, description="false marks 10 Hz nuScenes non-key frames")
    session_id: Int64 | None = Field(
        default=None,
        description="random id of the publisher's run: a new value marks a restarted stream",
    )
    boxes: BoxColumns

    def pose_matrix(self) -> npt.NDArray[np.float64] | None:
        return None if self.pose is None else np.asarray(self.pose, np.float64).reshape(4, 4)


class DetectionFrame(DetectionFrameV1):
    """One sensor frame of 3D detections: ``<prefix>/<vehicle>/<sensor>/detections``
    (version 2: the optional sensor->vehicle extrinsic)."""

    schema_version: Literal[2] = Field(  # type: ignore[assignment]  # v1 is a separate model
        description="2 for this layout (1: DetectionFrameV1, without extrinsic)"
    )
    extrinsic: Extrinsic | None = Field(
        default=None,
        description="sensor->vehicle 4x4 rigid transform, row-major: the sensor's mounting, "
        "by which a vehicle's fused tracker puts its boxes in the vehicle's frame",
    )

    @model_serializer(mode="wrap")
    def _omit_absent_extrinsic(self, handler: SerializerFunctionWrapHandler) -> dict[str, Any]:
        # Absent rather than nil, as the encoders write it (simpletrack.wire.messages.OMIT_NONE).
        out: dict[str, Any] = handler(self)
        if out.get("extrinsic", 0) is None:
            del out["extrinsic"]
        return out


class TrackFrameV1(_Header):
    """The tracks after one detection frame: ``<prefix>/<vehicle>/<sensor>/tracks``
    (version 1, what a service with ``tracks_schema_version`` 1 sends).

    ``seq`` and ``stamp_ns`` echo the detection frame's."""

    frame_id: Annotated[str, Field(min_length=1, max_length=128)] = Field(
        description="the tracking frame: the world frame when a pose was given, else the sensor's"
    )
    pose: Pose | None = Field(default=None, description="the detection frame's pose, echoed")
    key_frame: bool = True
    instance: Name = Field(description="id of the service instance that tracked the frame")
    received_ns: Int64 = Field(description="service wall clock (unix ns) at receipt")
    published_ns: Int64 = Field(description="service wall clock (unix ns) at publication")
    tracks: TrackColumnsV1


class TrackFrameV2(TrackFrameV1):
    """The tracks after one detection frame: ``<prefix>/<vehicle>/<sensor>/tracks``
    (version 2: covariance and ages in seconds).

    ``seq`` and ``stamp_ns`` echo the detection frame's."""

    schema_version: Literal[2] = Field(  # type: ignore[assignment]  # v1 is a separate model
        description="2 for this layout (1: TrackFrameV1)"
    )
    tracks: TrackColumns


# Both tracks messages' custody epoch (schemas/README.md, "Custody epoch (fencing)").
_EPOCH_DOC = (
    "custody epoch of the stream: higher each time another holder takes it over; a message "
    "with an epoch below the highest seen on its stream comes from a fenced holder: drop it"
)


def _without_nil_epoch(out: dict[str, Any]) -> dict[str, Any]:
    # Absent rather than nil, as the encoders write it (simpletrack.wire.messages.OMIT_NONE).
    if out.get("epoch", 0) is None:
        del out["epoch"]
    return out


class TrackFrame(TrackFrameV2):
    """The tracks after one detection frame: ``<prefix>/<vehicle>/<sensor>/tracks``
    (version 3: version 2 and the optional custody epoch).

    ``seq`` and ``stamp_ns`` echo the detection frame's."""

    schema_version: Literal[3] = Field(  # type: ignore[assignment]  # v2 is a separate model
        description="3 for this layout (2: TrackFrameV2, 1: TrackFrameV1)"
    )
    epoch: Int64 | None = Field(default=None, description=_EPOCH_DOC)

    @model_serializer(mode="wrap")
    def _omit_absent_epoch(self, handler: SerializerFunctionWrapHandler) -> dict[str, Any]:
        return _without_nil_epoch(handler(self))


class VehicleTrackColumns(TrackColumns):
    """A vehicle's N fused tracks as columns: a TrackFrame version 2's and two more."""

    existence: bytes = _column(
        VEHICLE_TRACK_SPECS["existence"], "float64 probability in [0, 1] that the track is real"
    )
    sensor_stamp_ns: bytes = _column(
        VEHICLE_TRACK_SPECS["sensor_stamp_ns"],
        "int64 count x len(sensors): stamp_ns of each sensor's last update of the track, "
        "-1 when that sensor never updated it",
    )


class VehicleTrackFrameV1(WireModel):
    """A vehicle's fused tracks: ``<prefix>/<vehicle>/@vehicle/tracks``, one tracker fed by
    the vehicle's sensors (version 1, without the epoch). (vehicle, seq, stamp_ns) identify
    a message: a repeat carries the same three."""

    schema_version: Literal[1] = Field(description="1 for this layout")
    vehicle: Name
    seq: Int64 = Field(
        description="the vehicle stream's message counter: +1 per message, kept across "
        "restarts and failovers"
    )
    stamp_ns: Int64 = Field(
        description="the time every box is at: the stamp of the input frame that produced it"
    )
    sensor: Name = Field(description="the sensor whose frame produced this message")
    sensor_seq: Int64 = Field(description="that frame's seq")
    frame_id: Annotated[str, Field(min_length=1, max_length=128)] = Field(
        description="the tracking frame: the world frame when the vehicle's frames carry "
        "poses, else the vehicle's frame"
    )
    pose: Pose | None = Field(default=None, description="the producing frame's pose, echoed")
    instance: Name = Field(description="id of the service instance that tracked the vehicle")
    received_ns: Int64 = Field(
        description="service wall clock (unix ns) at receipt of the producing frame"
    )
    published_ns: Int64 = Field(description="service wall clock (unix ns) at publication")
    sensors: Annotated[list[Name], Field(min_length=1, max_length=MAX_FUSED_SENSORS)] = Field(
        description="the vehicle's fused sensors, unique: the order of sensor_state and of "
        "the columns of tracks.sensor_stamp_ns"
    )
    sensor_state: Annotated[list[Condition], Field(max_length=MAX_FUSED_SENSORS)] = Field(
        description="each sensor's condition, in the order of sensors"
    )
    tracks: VehicleTrackColumns

    def pose_matrix(self) -> npt.NDArray[np.float64] | None:
        return None if self.pose is None else np.asarray(self.pose, np.float64).reshape(4, 4)


class VehicleTrackFrame(VehicleTrackFrameV1):
    """A vehicle's fused tracks: ``<prefix>/<vehicle>/@vehicle/tracks`` (version 2: version 1
    and the optional custody epoch)."""

    schema_version: Literal[2] = Field(  # type: ignore[assignment]  # v1 is a separate model
        description="2 for this layout (1: VehicleTrackFrameV1)"
    )
    epoch: Int64 | None = Field(default=None, description=_EPOCH_DOC)

    @model_serializer(mode="wrap")
    def _omit_absent_epoch(self, handler: SerializerFunctionWrapHandler) -> dict[str, Any]:
        return _without_nil_epoch(handler(self))


class FrameError(WireModel):
    """A frame that was not tracked: ``<prefix>/<vehicle>/<sensor>/errors``.

    ``vehicle``/``sensor`` come from the key the frame arrived on; ``seq``/``stamp_ns`` are
    nil when the payload was too broken to read them."""

    schema_version: Literal[1]
    vehicle: Name
    sensor: Name
    seq: Int64 | None = None
    stamp_ns: Int64 | None = None
    reason: Annotated[ErrorReason, Field(strict=False)] = Field(
        description="why: one of the ErrorReason values (schemas/README.md)"
    )
    field: Annotated[str, Field(max_length=256)] | None = Field(
        default=None, description="dotted path of the offending field, e.g. boxes.size"
    )
    detail: Annotated[str, Field(max_length=1024)] = Field(description="human-readable")
    instance: Name
    received_ns: Int64
    seqs: Annotated[list[Int64 | None], Field(max_length=MAX_NOTICE_SEQS)] | None = Field(
        default=None,
        description="drop notices: the seq of every frame the notice stands for, in arrival "
        "order (nil: unreadable); absent on other errors (schemas/README.md)",
    )

    @model_serializer(mode="wrap")
    def _omit_absent_seqs(self, handler: SerializerFunctionWrapHandler) -> dict[str, Any]:
        # Absent rather than nil, so an error without it is the message it always was.
        out: dict[str, Any] = handler(self)
        if out.get("seqs", 0) is None:
            del out["seqs"]
        return out


class SensorStatus(WireModel):
    vehicle: Name
    sensor: Name
    last_seq: Int64 | None
    last_stamp_ns: Int64 | None
    frames: Int64
    active_tracks: Int64
    idle_s: float
    rate_hz: float = Field(default=0.0, description="frames tracked per second over the last 10 s")
    resets: Int64 = Field(
        default=0, description="tracker resets (gap, time_backwards, restart, non_finite) here"
    )
    implausible_frames: Int64 = Field(
        default=0,
        description="frames tracked with a plausibility warning (units, conventions) here",
    )


class FusedSensorStatus(WireModel):
    """One sensor of a fused vehicle, as the vehicle's tracker sees it."""

    sensor: Name
    state: Condition = Field(description="the sensor's condition (SensorCondition)")
    last_seq: Int64 | None
    last_stamp_ns: Int64 | None
    frames: Int64 = Field(description="its frames applied to the vehicle's tracks")
    idle_s: float | None = Field(description="seconds since its last frame arrived")
    latency_s: float | None = Field(
        description="median stamp -> receipt over its recent frames, seconds"
    )
    clock_offset_s: float | None = Field(description="estimated offset of its clock, seconds")
    offset_m: Annotated[list[float], Field(min_length=2, max_length=2)] | None = Field(
        description="estimated x, y offset of its detections from the vehicle's tracks, metres"
    )
    flagged_frames: Int64 = Field(description="its frames kept out (clock or extrinsic)")
    detail: Annotated[str, Field(max_length=256)] = Field(
        default="", description="why it is flagged; empty when ok"
    )


class VehicleStatus(WireModel):
    """A fused vehicle: one tracker fed by its sensors."""

    vehicle: Name
    seq: Int64 | None = Field(description="seq of its last VehicleTrackFrame")
    last_stamp_ns: Int64 | None
    active_tracks: Int64
    frames: Int64 = Field(description="input frames applied")
    late_frames: Int64 = Field(description="frames refused as late")
    reprocessed_frames: Int64 = Field(description="frames applied again after a late one")
    sensors: Annotated[list[FusedSensorStatus], Field(max_length=MAX_FUSED_SENSORS)]


class ServiceStatusV1(WireModel):
    """Reply of the status queryable ``<prefix>/@simpletrack/<instance>/status`` (version 1,
    without vehicles)."""

    schema_version: Literal[1]
    instance: Name
    version: str
    preset: str
    classes: list[str]
    config_digest: str = Field(description="sha256 of the tracker configuration in use")
    started_ns: Int64
    ready: bool
    queue_depth: Int64
    sensors: list[SensorStatus] = Field(description="the sensors this instance holds (owns)")
    members: list[Name] = Field(
        default_factory=list,
        description="the live instances on this prefix in this one's view, itself included",
    )
    standby_sensors: Int64 = Field(default=0, description="sensors this instance stands by for")
    handoffs_in: Int64 = Field(default=0, description="sensors received from a live member")
    handoffs_out: Int64 = Field(default=0, description="sensors given to a live member")
    failovers: Int64 = Field(default=0, description="sensors taken over from a member gone")


class ServiceStatus(ServiceStatusV1):
    """Reply of the status queryable ``<prefix>/@simpletrack/<instance>/status`` (version 2:
    the fused vehicles)."""

    schema_version: Literal[2]  # type: ignore[assignment]  # v1 is a separate model
    vehicles: list[VehicleStatus] = Field(
        default_factory=list, description="the fused vehicles this instance holds"
    )


class SensorSnapshot(WireModel):
    """One sensor's tracker state: the snapshot file format, and the reply of the snapshot
    queryable ``<prefix>/@simpletrack/<instance>/snapshot/<vehicle>/<sensor>``."""

    schema_version: Literal[1]
    vehicle: Name
    sensor: Annotated[str, Field(pattern=SNAPSHOT_SENSOR_PATTERN)] = Field(
        description="the sensor, or @vehicle for a fused vehicle's tracker"
    )
    last_seq: Int64 | None = None
    last_stamp_ns: Int64 | None = None
    stamp_origin_ns: Int64 | None = Field(
        default=None, description="tracker time 0: the tracker sees (stamp_ns - origin) * 1e-9 s"
    )
    id_base: Int64 = Field(default=0, description="added to tracker ids; raised on every reset")
    id_next: Int64 = Field(default=0, description="lowest id never published on this stream")
    frames: Int64 = 0
    last_received_ns: Int64 | None = Field(
        default=None, description="service wall clock (unix ns) at receipt of the last frame"
    )
    last_session_id: Int64 | None = Field(
        default=None, description="session_id of the last frame (nil: none given)"
    )
    config_digest: str = Field(description="sha256 of the tracker configuration")
    tracker: bytes | None = Field(default=None, description="opaque Tracker.to_bytes() blob")
    written_ns: Int64
    epoch: Int64 | None = Field(
        default=None,
        description="the stream's custody epoch when written (nil: a service of before epochs)",
    )


MESSAGES: tuple[type[WireModel], ...] = (
    DetectionFrame,
    DetectionFrameV1,
    TrackFrame,
    TrackFrameV2,
    TrackFrameV1,
    VehicleTrackFrame,
    VehicleTrackFrameV1,
    FrameError,
    ServiceStatus,
    ServiceStatusV1,
    SensorSnapshot,
)
