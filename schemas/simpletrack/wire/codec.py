"""Encode and decode wire messages. Decoders never raise: they return the decoded message or a
``Rejection`` naming the reason and the offending field (order of checks: schemas/README.md).
"""

from __future__ import annotations

import math
import re
import sys
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import Any, Protocol, TypeVar, cast

import msgpack
import numpy as np
import numpy.typing as npt

from simpletrack.wire.columns import (
    DETECTION_COLUMNS,
    DETECTION_SPECS,
    TRACK_COLUMNS_OF,
    BoxArrays,
    TrackArrays,
    to_column,
)
from simpletrack.wire.decoding import (
    DEFAULT_LIMITS,
    Extents,
    Reject,
    check_version,
    internal_error,
    plan,
    read_columns,
    rejection,
    unpack,
    validate,
)
from simpletrack.wire.decoding import (
    DecodeLimits as DecodeLimits,
)
from simpletrack.wire.decoding import (
    Rejection as Rejection,
)
from simpletrack.wire.fields import Invalid
from simpletrack.wire.messages import (
    BOX_COLUMNS,
    DETECTION_FRAMES,
    INT64_MAX,
    MAX_NOTICE_SEQS,
    MESSAGE_TYPES,
    NAME_PATTERN,
    SPECS,
    TRACK_FRAMES,
    VERSIONS,
    DetectionFrame,
    FrameError,
    Message,
    TrackFrame,
    spec_of,
    to_map,
)
from simpletrack.wire.reasons import (
    DETECTION_SCHEMA_VERSION,
    DETECTION_SCHEMA_VERSIONS,
    SCHEMA_VERSION,
    TRACK_EPOCH_SCHEMA_VERSION,
    TRACK_SCHEMA_VERSION,
    TRACK_SCHEMA_VERSIONS,
    ErrorReason,
)

M = TypeVar("M")
F32 = npt.NDArray[np.float32]
F64 = npt.NDArray[np.float64]
I32 = npt.NDArray[np.int32]

# Rotation part of a pose must be orthonormal to this tolerance (float32-sourced poses pass).
POSE_TOLERANCE = 1e-4
_EYE3 = np.eye(3)

# Plausibility bounds of a detection (schemas/README.md, "Bounds"). Beyond them a value is a
# bug upstream, float32 has too few digits left to mean anything (its spacing at 1e5 is 8 mm),
# and the tracker's arithmetic could leave float32 on the way out (3.4e38 m boxes used to
# come back as inf). Scores are not bounded: the tracker only copies and decays them.
MAX_COORDINATE_M = 1e5  # |x|, |y|, |z| of a centre and of a pose's translation
MAX_SIZE_M = 100.0  # each of l, w, h
MAX_YAW_RAD = 1e4
MAX_SPEED_MPS = 200.0  # |vx|, |vy|


@dataclass(frozen=True, slots=True)
class DecodedDetections:
    frame: DetectionFrame
    boxes: BoxArrays
    pose: F64 | None
    # Version 2: the sensor->vehicle transform (None when the frame has none).
    extrinsic: F64 | None
    # Per box: the code of its class in the caller's table (``class_codes``), -1 for a
    # class the caller mapped to -1 (ignored). None when no table was given.
    codes: I32 | None
    # The least and greatest value of each float column (``center``, ``size``, ``yaw``,
    # ``score``, ``velocity`` when sent) over every row and axis; empty for a frame without
    # boxes. What the plausibility checks read instead of reducing the columns again.
    extents: Extents = field(default_factory=dict)


class _PydanticModel(Protocol):
    """A model of ``simpletrack.wire.models`` (what the server builds its replies from)."""

    def model_dump(self, *, mode: str = ...) -> dict[str, Any]: ...


def pack(obj: Any) -> bytes:
    return bytes(msgpack.packb(obj, use_bin_type=True))


def encode(message: Message | _PydanticModel) -> bytes:
    """Any wire message (a ``simpletrack.wire`` message or its pydantic model) as msgpack;
    bytes fields become ``bin``. A message the decoders would refuse raises ValueError."""
    if type(message) is FrameError:
        checked = _frame_error_map(message)
        if checked is not None:
            return pack(checked)
    if not isinstance(message, MESSAGE_TYPES):
        return pack(message.model_dump(mode="python"))
    obj = to_map(message)
    try:
        spec_of(message)(obj)
    except Invalid as e:
        raise ValueError(f"{type(message).__name__}.{e.field}: {e.detail}") from None
    return pack(obj)


_NAME = re.compile(NAME_PATTERN)


def _int64(v: Any) -> bool:
    return type(v) is int and 0 <= v <= INT64_MAX


def _frame_error_map(e: FrameError) -> dict[str, Any] | None:
    """A ``FrameError``'s map, checked field by field without the table's walk: a worker
    refuses garbage by the thousand (building and encoding one: ~4 µs this way, ~13 µs
    through the table, ~7 µs as the pydantic model it replaced). None when a value is not
    plainly valid: ``encode``'s general path then decides (and names the field). Whatever
    passes here the table accepts, and the map is ``to_map``'s, so the bytes are the same
    (tests/wire/test_validator_agrees.py, tests/server/test_outbox.py)."""
    seqs = e.seqs
    plain = (
        type(e.schema_version) is int
        and e.schema_version == SCHEMA_VERSION
        and type(e.vehicle) is str
        and _NAME.fullmatch(e.vehicle) is not None
        and type(e.sensor) is str
        and _NAME.fullmatch(e.sensor) is not None
        and (e.seq is None or _int64(e.seq))
        and (e.stamp_ns is None or _int64(e.stamp_ns))
        and type(e.reason) is ErrorReason
        and (e.field is None or (type(e.field) is str and len(e.field) <= 256))
        and type(e.detail) is str
        and len(e.detail) <= 1024
        and type(e.instance) is str
        and _NAME.fullmatch(e.instance) is not None
        and _int64(e.received_ns)
        and (
            seqs is None
            or (
                type(seqs) is list
                and len(seqs) <= MAX_NOTICE_SEQS
                and all(v is None or _int64(v) for v in seqs)
            )
        )
    )
    if not plain:
        return None
    obj: dict[str, Any] = {
        "schema_version": e.schema_version,
        "vehicle": e.vehicle,
        "sensor": e.sensor,
        "seq": e.seq,
        "stamp_ns": e.stamp_ns,
        "reason": e.reason,
        "field": e.field,
        "detail": e.detail,
        "instance": e.instance,
        "received_ns": e.received_ns,
    }
    if seqs is not None:  # absent, not nil (the message of before the field existed)
        obj["seqs"] = list(seqs)
    return obj


# --- decoding -----------------------------------------------------------------------------

_DETECTION_PLAN = plan(DETECTION_COLUMNS, "boxes")
_least = np.minimum.reduce
_greatest = np.maximum.reduce
_TRACK_PLANS = {v: plan(cols, "tracks") for v, cols in TRACK_COLUMNS_OF.items()}


def _bounded(
    arr: npt.NDArray[Any], extent: tuple[float, float] | None, bound: float, field: str, unit: str
) -> None:
    # The column's extent (read_columns's) on the hot path; the offending row is looked for
    # only on failure.
    if extent is None or max(-extent[0], extent[1]) <= bound:
        return
    row = int(np.argwhere(np.abs(arr) > bound)[0][0])
    raise Reject(ErrorReason.INVALID_VALUE, field, f"|value| over {bound:g} {unit} in row {row}")


def _check_bounds(boxes: BoxArrays, extents: Extents) -> None:
    """Each column's values within their bound (a column of no rows has no extent)."""
    get = extents.get
    _bounded(boxes.center, get("center"), MAX_COORDINATE_M, "boxes.center", "m")
    _bounded(boxes.size, get("size"), MAX_SIZE_M, "boxes.size", "m")
    _bounded(boxes.yaw, get("yaw"), MAX_YAW_RAD, "boxes.yaw", "rad")
    if boxes.velocity is not None:
        _bounded(boxes.velocity, get("velocity"), MAX_SPEED_MPS, "boxes.velocity", "m/s")


def _det3(p: list[float]) -> float:
    """Determinant of the rotation part of a row-major 4x4 (only its sign is used)."""
    return (
        p[0] * (p[5] * p[10] - p[6] * p[9])
        - p[1] * (p[4] * p[10] - p[6] * p[8])
        + p[2] * (p[4] * p[9] - p[5] * p[8])
    )


def rigid_transform(p: list[float] | None, field: str) -> F64 | None:
    """A pose or extrinsic as a 4x4: finite, rigid, its translation within bounds."""
    # Scalar checks on the 16 Python floats where numpy's per-call cost would dominate.
    if p is None:
        return None
    if not all(map(math.isfinite, p)):
        raise Reject(ErrorReason.NON_FINITE, field, f"NaN or inf in the {field}")
    pose = np.array(p, np.float64).reshape(4, 4)
    rot = pose[:3, :3]
    rigid = (
        max(abs(p[12]), abs(p[13]), abs(p[14]), abs(p[15] - 1.0)) <= POSE_TOLERANCE
        # An entry over 1 + tolerance already fails orthonormality (its row's norm); said
        # first, a huge one never reaches the product, which would overflow (a warning the
        # service logs as a floating-point fault).
        and max(map(abs, (*p[0:3], *p[4:7], *p[8:11]))) <= 1.0 + POSE_TOLERANCE
        and np.abs(rot @ rot.T - _EYE3).max() <= POSE_TOLERANCE
        and _det3(p) > 0
    )
    if not rigid:
        raise Reject(ErrorReason.INVALID_VALUE, field, "not a rigid transform (row-major 4x4)")
    if max(abs(p[3]), abs(p[7]), abs(p[11])) > MAX_COORDINATE_M:
        raise Reject(ErrorReason.INVALID_VALUE, field, f"translation over {MAX_COORDINATE_M:g} m")
    return pose


# (id of a caller's class_codes, a frame's class table) -> (that class_codes, a copy of
# it, the codes of the table's names, -2 for a name it lacks; whether any is -2). A sensor
# sends the same table frame after frame. The caller's mapping is held, so its id names it
# while cached; the copy says whether it changed since (then the table is worked out again).
_CodeTable = tuple[Mapping[str, int], dict[str, int], I32, bool]
_CODE_TABLES: dict[tuple[int, tuple[str, ...]], _CodeTable] = {}
_CODE_TABLES_CAP = 256  # tables come from the fleet: bounded, cleared whole past it


def _code_table(classes: tuple[str, ...], class_codes: Mapping[str, int]) -> tuple[I32, bool]:
    key = (id(class_codes), classes)
    hit = _CODE_TABLES.get(key)
    if hit is not None and hit[0] is class_codes and hit[1] == class_codes:
        return hit[2], hit[3]
    table = np.array([class_codes.get(name, -2) for name in classes], dtype=np.int32)
    unknown = bool((table == -2).any())
    if len(_CODE_TABLES) >= _CODE_TABLES_CAP:
        _CODE_TABLES.clear()
    _CODE_TABLES[key] = (class_codes, dict(class_codes), table, unknown)
    return table, unknown


def _class_codes(boxes: BoxArrays, class_codes: Mapping[str, int]) -> I32:
    table, any_unknown = _code_table(boxes.classes, class_codes)
    codes: I32 = table[boxes.class_index]
    if not any_unknown:  # every name of the table is known: so is every box's class
        return codes
    unknown = codes == -2
    if unknown.any():
        idx = int(boxes.class_index[int(np.argmax(unknown))])
        raise Reject(
            ErrorReason.UNKNOWN_CLASS,
            f"boxes.classes.{idx}",
            f"class {boxes.classes[idx]!r} is not tracked here; known: {', '.join(class_codes)}"[
                :300
            ],
        )
    return codes


# The least and greatest of a frame's centre, size, yaw, score, velocity (None when not sent)
# and class index columns, in one call: a (6, 2) array, or None to reduce them one by one (the
# service's compiled reduction: wire/convert.py detection_extents).
ExtentsOf = Callable[[F32, F32, F32, F64, F32 | None, I32], F64 | None]


def decode_detection_frame(
    payload: bytes,
    limits: DecodeLimits = DEFAULT_LIMITS,
    class_codes: Mapping[str, int] | None = None,
    extents_of: ExtentsOf | None = None,
) -> DecodedDetections | Rejection:
    """Decode and validate a ``DetectionFrame`` (version 1 or 2). ``class_codes`` maps class
    names to the caller's codes (-1 = known but ignored); a box of any other class is
    ``unknown_class``. ``extents_of`` reduces the columns in one call; a frame whose columns
    it finds anything wrong with is judged column by column (the same refusals either way)."""
    obj: dict[str, Any] = {}
    try:
        obj = unpack(payload, limits)
        version = check_version(obj, DETECTION_SCHEMA_VERSIONS)
        frame = validate(DETECTION_FRAMES[version], obj)
        extents: Extents = {}
        judged = None
        if extents_of is not None:
            judged = _judged_columns(frame.boxes, limits.max_boxes, extents, extents_of)
        index_extent: tuple[int, int] | None = None
        if judged is None:
            cols = read_columns(frame.boxes, _DETECTION_PLAN, "boxes", limits.max_boxes, 0, extents)
        else:
            cols, index_extent = judged
        boxes = BoxArrays(classes=tuple(frame.boxes.classes), **cols)
        n_classes = len(boxes.classes)
        if len(boxes) and index_extent is None:
            index_extent = int(_least(boxes.class_index)), int(_greatest(boxes.class_index))
        if index_extent is not None and (index_extent[0] < 0 or index_extent[1] >= n_classes):
            raise Reject(
                ErrorReason.INVALID_VALUE,
                "boxes.class_index",
                f"index outside the class table of {n_classes} entries",
            )
        if len(boxes) and not extents["size"][0] > 0:  # finite already: the least says it
            row = int(np.argwhere(~(boxes.size > 0))[0][0])
            raise Reject(ErrorReason.NON_POSITIVE_SIZE, "boxes.size", f"size <= 0 in row {row}")
        _check_bounds(boxes, extents)
        pose = rigid_transform(frame.pose, "pose")
        extrinsic = rigid_transform(frame.extrinsic, "extrinsic")
        codes = None if class_codes is None else _class_codes(boxes, class_codes)
        return DecodedDetections(frame, boxes, pose, extrinsic, codes, extents)
    except Reject as r:
        return rejection(r, obj)
    except Exception as e:  # a bug in this module; the fuzz test asserts it never happens
        return internal_error(e)


def _judged_columns(
    model: Any, max_rows: int, extents: Extents, extents_of: ExtentsOf
) -> tuple[dict[str, npt.NDArray[Any]], tuple[int, int]] | None:
    """The columns of a frame of at least one box, with their extents from ``extents_of``
    (into ``extents``) and the class indices' (least, greatest); None for anything else
    (no rows, too many, a column's length, NaN or inf, no answer): ``read_columns`` then
    says which check fails first."""
    count = int(model.count)
    if not 0 < count <= max_rows:
        return None
    cols: dict[str, npt.NDArray[Any]] = {}
    for c in _DETECTION_PLAN:
        buf = getattr(model, c.name)
        if buf is None:
            continue
        if len(buf) != count * c.row_bytes:
            return None
        arr = np.frombuffer(buf, dtype=c.dtype)
        cols[c.name] = arr.reshape(count, c.width) if c.width > 1 else arr
    velocity = cols.get("velocity")
    found = extents_of(
        cols["center"], cols["size"], cols["yaw"], cols["score"], velocity, cols["class_index"]
    )
    if found is None:
        return None
    (c0, c1), (s0, s1), (y0, y1), (r0, r1), (v0, v1), (i0, i1) = found.tolist()
    floats = [c0, c1, s0, s1, y0, y1, r0, r1] + ([] if velocity is None else [v0, v1])
    if not all(map(math.isfinite, floats)):
        return None
    extents.update(center=(c0, c1), size=(s0, s1), yaw=(y0, y1), score=(r0, r1))
    if velocity is not None:
        extents["velocity"] = (v0, v1)
    return cols, (int(i0), int(i1))


def decode_track_frame(
    payload: bytes,
    limits: DecodeLimits = DEFAULT_LIMITS,
) -> tuple[TrackFrame, TrackArrays] | Rejection:
    """Decode and validate a ``TrackFrame`` (version 1, 2 or 3); the frame's ``epoch`` is
    None unless a version-3 frame carries one."""
    obj: dict[str, Any] = {}
    try:
        obj = unpack(payload, limits)
        version = check_version(obj, TRACK_SCHEMA_VERSIONS)
        frame = validate(TRACK_FRAMES[version], obj)
        cols = read_columns(frame.tracks, _TRACK_PLANS[version], "tracks", limits.max_boxes)
        return frame, TrackArrays(classes=tuple(frame.tracks.classes), **cols)
    except Reject as r:
        return rejection(r, obj)
    except Exception as e:
        return internal_error(e)


def decode_message(
    payload: bytes,
    model: type[M],
    limits: DecodeLimits = DEFAULT_LIMITS,
) -> M | Rejection:
    """Decode any other message (FrameError, ServiceStatus, SensorSnapshot). ``model`` is a
    message class of ``simpletrack.wire``, or its pydantic twin of ``simpletrack.wire.models``
    (the server's): the same checks decide, then the twin is built from the map. A message
    read in several versions is checked against its version's table; asked for as a pydantic
    model, an earlier version comes back as that version's model (``ServiceStatusV1``)."""
    try:
        obj = unpack(payload, limits)
        versions = VERSIONS.get(model.__name__)
        if versions is None:
            check_version(obj)
            spec = SPECS[model.__name__]
        else:
            spec = versions[check_version(obj, tuple(versions))]
        message = validate(spec, obj)
        if isinstance(message, model):
            return message
        twin: Any = getattr(sys.modules[model.__module__], spec.name, model)
        return cast(M, twin.model_validate(obj))
    except Reject as r:
        return Rejection(r.reason, r.field, r.detail)
    except Exception as e:
        return internal_error(e)


# --- fast encoders for the hot path (no pydantic round trip) --------------------------------


def encode_detection_frame(
    *,
    vehicle: str,
    sensor: str,
    seq: int,
    stamp_ns: int,
    frame_id: str,
    boxes: BoxArrays,
    pose: npt.ArrayLike | None = None,
    key_frame: bool = True,
    session_id: int | None = None,
    extrinsic: npt.ArrayLike | None = None,
) -> bytes:
    """A ``DetectionFrame`` from numpy columns (what a vehicle-side publisher calls).
    ValueError for a column of the wrong shape or a bad class table. ``session_id`` None
    leaves the field out (the frame a publisher of before the field would send). Version 1
    without ``extrinsic`` (the bytes of before version 2), version 2 with it."""
    s = DETECTION_SPECS
    ci = to_column(boxes.class_index, s["class_index"])
    cols: dict[str, Any] = {
        "count": len(ci) // 4,
        "classes": list(boxes.classes),
        "class_index": ci,
        "center": to_column(boxes.center, s["center"]),
        "size": to_column(boxes.size, s["size"]),
        "yaw": to_column(boxes.yaw, s["yaw"]),
        "score": to_column(boxes.score, s["score"]),
    }
    if boxes.velocity is not None:
        cols["velocity"] = to_column(boxes.velocity, s["velocity"])
    try:
        BOX_COLUMNS(cols)
    except Invalid as e:
        raise ValueError(f"boxes.{e.field}: {e.detail}") from None
    msg: dict[str, Any] = {
        "schema_version": SCHEMA_VERSION if extrinsic is None else DETECTION_SCHEMA_VERSION,
        "vehicle": vehicle,
        "sensor": sensor,
        "seq": int(seq),
        "stamp_ns": int(stamp_ns),
        "frame_id": frame_id,
        "key_frame": bool(key_frame),
        "boxes": cols,
    }
    if pose is not None:
        msg["pose"] = transform_list(pose)
    if session_id is not None:
        msg["session_id"] = int(session_id)
    if extrinsic is not None:
        msg["extrinsic"] = transform_list(extrinsic)
    return pack(msg)


def transform_list(transform: npt.ArrayLike) -> list[float]:
    """A 4x4 (or 16 values) as the 16 floats of the wire, row-major."""
    return [float(v) for v in np.asarray(transform, dtype=np.float64).reshape(16)]


def encode_track_frame(
    *,
    vehicle: str,
    sensor: str,
    seq: int,
    stamp_ns: int,
    frame_id: str,
    pose: list[float] | None,
    key_frame: bool,
    instance: str,
    received_ns: int,
    published_ns: int,
    tracks: TrackArrays | bytes,
    schema_version: int | None = None,
    epoch: int | None = None,
) -> bytes:
    """A ``TrackFrame`` of the given version. An earlier version leaves out what later ones
    added, for fleets with readers of that version: 1 version 2's columns, 1 and 2 the
    ``epoch``. None: the newest version the arguments fill (3 with ages in seconds and an
    epoch, 2 with ages only, else 1: what a caller of before each version gets). ``epoch``
    None leaves the key out. ``tracks`` as bytes is the ``tracks`` map packed already
    (convert.py ``pack_tracks_checked``, for this ``schema_version``, which must be given).
    ValueError for a bad version or epoch, a column of the wrong shape, or a frame of
    version 2 or 3 without ages in seconds."""
    check_epoch(epoch)
    if isinstance(tracks, bytes):
        if schema_version not in TRACK_COLUMNS_OF:
            raise ValueError(
                f"packed tracks need a TrackFrame schema_version of 1, 2 or 3, not {schema_version!r}"
            )
    elif schema_version is None:
        has_ages = tracks.age_s is not None and tracks.time_since_update_s is not None
        schema_version = 1
        if has_ages:
            schema_version = TRACK_SCHEMA_VERSION if epoch is None else TRACK_EPOCH_SCHEMA_VERSION
    if schema_version not in TRACK_COLUMNS_OF:
        raise ValueError(f"TrackFrame schema_version {schema_version!r} is not one of 1, 2, 3")
    msg: dict[str, Any] = {
        "schema_version": schema_version,
        "vehicle": vehicle,
        "sensor": sensor,
        "seq": seq,
        "stamp_ns": stamp_ns,
        "frame_id": frame_id,
        "pose": pose,
        "key_frame": key_frame,
        "instance": instance,
        "received_ns": received_ns,
        "published_ns": published_ns,
    }
    if isinstance(tracks, bytes):
        with_epoch = epoch is not None and schema_version >= TRACK_EPOCH_SCHEMA_VERSION
        return packed_around(msg, tracks, epoch if with_epoch else None)
    columns: dict[str, Any] = {"count": len(tracks), "classes": list(tracks.classes)}
    for spec, dtype in _TRACK_DTYPES[schema_version]:
        values = getattr(tracks, spec.name)
        if values is None:
            if not spec.optional:
                raise ValueError(f"a version {schema_version} TrackFrame needs {spec.name}")
            continue
        # A column as tracks_to_wire makes it (its dtype, contiguous, its width) is its
        # bytes as they are; anything else goes through to_column's conversion and checks.
        if (
            type(values) is np.ndarray
            and values.dtype == dtype
            and values.flags.c_contiguous
            and (
                values.ndim == 1
                if spec.width == 1
                else values.ndim == 2 and values.shape[1] == spec.width
            )
        ):
            columns[spec.name] = values.tobytes()
        else:
            columns[spec.name] = to_column(values, spec)
    msg["tracks"] = columns
    if epoch is not None and schema_version >= TRACK_EPOCH_SCHEMA_VERSION:
        msg["epoch"] = epoch
    return pack(msg)


def packed_around(header: dict[str, Any], tracks: bytes, epoch: int | None) -> bytes:
    """A track message (TrackFrame, VehicleTrackFrame) whose ``tracks`` map is packed
    already: ``header`` (the entries before ``tracks``, at most 13: a fixmap), then
    ``tracks``, then the ``epoch`` where there is one; the bytes msgpack writes for the whole
    map."""
    entries = len(header) + 1 + (epoch is not None)
    tail = b"" if epoch is None else _EPOCH_KEY + pack(epoch)
    return b"".join((bytes([0x80 | entries]), pack(header)[1:], _TRACKS_KEY, tracks, tail))


_TRACKS_KEY, _EPOCH_KEY = pack("tracks"), pack("epoch")


# Each TrackFrame version's columns with their numpy dtypes, worked out once.
_TRACK_DTYPES = {
    v: tuple((spec, np.dtype(spec.dtype)) for spec in specs)
    for v, specs in TRACK_COLUMNS_OF.items()
}


def check_epoch(epoch: int | None) -> None:
    """ValueError unless ``epoch`` is None or what the wire's ``epoch`` holds: an int in
    [0, 2**63 - 1] (a bool is no epoch)."""
    if epoch is not None and (type(epoch) is not int or not 0 <= epoch <= INT64_MAX):
        raise ValueError(f"epoch must be an int in [0, 2**63 - 1], got {epoch!r}")
