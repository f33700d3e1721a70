"""Encode and decode wire messages. Decoders never raise: they return the decoded message or a
``Rejection`` naming the reason and the offending field (order of checks: schemas/README.md).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any, TypeVar

import msgpack
import numpy as np
import numpy.typing as npt
from pydantic import ValidationError

from simpletrack.wire.columns import (
    DETECTION_COLUMNS,
    TRACK_COLUMNS,
    TRACK_SPECS,
    BoxArrays,
    ColumnSpec,
    TrackArrays,
    to_column,
    view_column,
)
from simpletrack.wire.models import BoxColumns, DetectionFrame, TrackFrame, WireModel
from simpletrack.wire.reasons import SCHEMA_VERSION, ErrorReason

M = TypeVar("M", bound=WireModel)
F64 = npt.NDArray[np.float64]
I32 = npt.NDArray[np.int32]

# Rotation part of a pose must be orthonormal to this tolerance (float32-sourced poses pass).
POSE_TOLERANCE = 1e-4


@dataclass(frozen=True, slots=True)
class DecodeLimits:
    max_bytes: int = 8 << 20
    max_boxes: int = 10_000


@dataclass(frozen=True, slots=True)
class Rejection:
    """Why a payload was refused; ``seq``/``stamp_ns`` when they could still be read."""

    reason: ErrorReason
    field: str | None
    detail: str
    seq: int | None = None
    stamp_ns: int | None = None


@dataclass(frozen=True, slots=True)
class DecodedDetections:
    frame: DetectionFrame
    boxes: BoxArrays
    pose: F64 | None
    # Per box: the code of its class in the caller's table (``class_codes``), -1 for a
    # class the caller mapped to -1 (ignored). None when no table was given.
    codes: I32 | None


class _Reject(Exception):
    def __init__(self, reason: ErrorReason, field: str | None, detail: str) -> None:
        super().__init__(detail)
        self.reason, self.field, self.detail = reason, field, detail


def pack(obj: Any) -> bytes:
    return bytes(msgpack.packb(obj, use_bin_type=True))


def encode(model: WireModel) -> bytes:
    """Any wire model as msgpack (bytes fields become ``bin``)."""
    return pack(model.model_dump(mode="python"))


# --- decoding -----------------------------------------------------------------------------


def _unpack(payload: bytes, limits: DecodeLimits) -> dict[str, Any]:
    if len(payload) > limits.max_bytes:
        raise _Reject(
            ErrorReason.TOO_LARGE,
            "payload",
            f"{len(payload)} bytes exceeds the cap of {limits.max_bytes}",
        )
    try:
        obj = msgpack.unpackb(payload, raw=False, strict_map_key=True)
    except (ValueError, TypeError, msgpack.UnpackException, RecursionError, OverflowError) as e:
        # ExtraData, FormatError, StackError and bad UTF-8 are all ValueError subclasses.
        raise _Reject(ErrorReason.MALFORMED, "payload", f"not msgpack: {e}"[:200]) from None
    if not isinstance(obj, dict):
        raise _Reject(ErrorReason.MALFORMED, "payload", f"expected a map, got {type(obj).__name__}")
    return obj


def _check_version(obj: dict[str, Any]) -> None:
    version = obj.get("schema_version")
    if "schema_version" not in obj:
        raise _Reject(ErrorReason.MISSING_FIELD, "schema_version", "field required")
    if type(version) is not int:
        raise _Reject(ErrorReason.WRONG_TYPE, "schema_version", "must be an integer")
    if version != SCHEMA_VERSION:
        raise _Reject(
            ErrorReason.WRONG_VERSION,
            "schema_version",
            f"version {version} not supported (this service speaks {SCHEMA_VERSION})",
        )


_MISSING = {"missing"}
_EXTRA = {"extra_forbidden"}


def _pydantic_reject(err: ValidationError) -> _Reject:
    first = err.errors(include_url=False)[0]
    field = ".".join(str(p) for p in first["loc"]) or None
    kind = first["type"]
    if kind in _MISSING:
        reason = ErrorReason.MISSING_FIELD
    elif kind in _EXTRA:
        reason = ErrorReason.EXTRA_FIELD
    elif kind.endswith("_type") or kind in {"model_attributes_type", "literal_error"}:
        reason = ErrorReason.WRONG_TYPE
    else:
        reason = ErrorReason.INVALID_VALUE
    return _Reject(reason, field, str(first["msg"])[:200])


def _validate(model: type[M], obj: dict[str, Any]) -> M:
    try:
        return model.model_validate(obj)
    except ValidationError as e:
        raise _pydantic_reject(e) from None


def _columns(
    model: Any, specs: tuple[ColumnSpec, ...], prefix: str, max_rows: int
) -> dict[str, npt.NDArray[Any]]:
    count = int(model.count)
    if count > max_rows:
        raise _Reject(
            ErrorReason.TOO_LARGE, f"{prefix}.count", f"{count} rows exceeds the cap of {max_rows}"
        )
    out: dict[str, npt.NDArray[Any]] = {}
    for spec in specs:
        buf = getattr(model, spec.name)
        if buf is None:
            continue
        field = f"{prefix}.{spec.name}"
        if len(buf) != count * spec.row_bytes:
            raise _Reject(
                ErrorReason.COLUMN_LENGTH,
                field,
                f"{len(buf)} bytes, expected count {count} x {spec.row_bytes} bytes",
            )
        arr = view_column(buf, spec)
        if spec.finite:
            bad = ~np.isfinite(arr)
            if bad.any():
                row = int(np.argwhere(bad)[0][0])
                raise _Reject(ErrorReason.NON_FINITE, field, f"NaN or inf in row {row}")
        out[spec.name] = arr
    return out


def _pose(frame: DetectionFrame) -> F64 | None:
    pose = frame.pose_matrix()
    if pose is None:
        return None
    if not np.isfinite(pose).all():
        raise _Reject(ErrorReason.NON_FINITE, "pose", "NaN or inf in the pose")
    rot = pose[:3, :3]
    rigid = (
        np.abs(pose[3] - (0.0, 0.0, 0.0, 1.0)).max() <= POSE_TOLERANCE
        and np.abs(rot @ rot.T - np.eye(3)).max() <= POSE_TOLERANCE
        and np.linalg.det(rot) > 0
    )
    if not rigid:
        raise _Reject(ErrorReason.INVALID_VALUE, "pose", "not a rigid transform (row-major 4x4)")
    return pose


def _class_codes(boxes: BoxArrays, class_codes: Mapping[str, int]) -> I32:
    table = np.full(len(boxes.classes), -2, dtype=np.int32)
    for i, name in enumerate(boxes.classes):
        table[i] = class_codes.get(name, -2)
    codes = table[boxes.class_index]
    unknown = codes == -2
    if unknown.any():
        idx = int(boxes.class_index[int(np.argmax(unknown))])
        raise _Reject(
            ErrorReason.UNKNOWN_CLASS,
            f"boxes.classes.{idx}",
            f"class {boxes.classes[idx]!r} is not tracked here; known: {', '.join(class_codes)}"[
                :300
            ],
        )
    return codes


def _peek_int(obj: Mapping[str, Any], key: str) -> int | None:
    v = obj.get(key)
    return v if type(v) is int and 0 <= v < 2**63 else None


def decode_detection_frame(
    payload: bytes,
    limits: DecodeLimits = DecodeLimits(),
    class_codes: Mapping[str, int] | None = None,
) -> DecodedDetections | Rejection:
    """Decode and validate a ``DetectionFrame``. ``class_codes`` maps class names to the
    caller's codes (-1 = known but ignored); a box of any other class is ``unknown_class``."""
    obj: dict[str, Any] = {}
    try:
        obj = _unpack(payload, limits)
        _check_version(obj)
        frame = _validate(DetectionFrame, obj)
        cols = _columns(frame.boxes, DETECTION_COLUMNS, "boxes", limits.max_boxes)
        boxes = BoxArrays(classes=tuple(frame.boxes.classes), **cols)
        n_classes = len(boxes.classes)
        if len(boxes) and (
            int(boxes.class_index.min()) < 0 or int(boxes.class_index.max()) >= n_classes
        ):
            raise _Reject(
                ErrorReason.INVALID_VALUE,
                "boxes.class_index",
                f"index outside the class table of {n_classes} entries",
            )
        if len(boxes) and not (boxes.size > 0).all():
            row = int(np.argwhere(~(boxes.size > 0))[0][0])
            raise _Reject(ErrorReason.NON_POSITIVE_SIZE, "boxes.size", f"size <= 0 in row {row}")
        pose = _pose(frame)
        codes = None if class_codes is None else _class_codes(boxes, class_codes)
        return DecodedDetections(frame=frame, boxes=boxes, pose=pose, codes=codes)
    except _Reject as r:
        return Rejection(
            r.reason, r.field, r.detail, _peek_int(obj, "seq"), _peek_int(obj, "stamp_ns")
        )
    except Exception as e:  # a bug in this module; the fuzz test asserts it never happens
        return Rejection(ErrorReason.INTERNAL_ERROR, None, f"{type(e).__name__}: {e}"[:300])


def decode_track_frame(
    payload: bytes,
    limits: DecodeLimits = DecodeLimits(),
) -> tuple[TrackFrame, TrackArrays] | Rejection:
    obj: dict[str, Any] = {}
    try:
        obj = _unpack(payload, limits)
        _check_version(obj)
        frame = _validate(TrackFrame, obj)
        cols = _columns(frame.tracks, TRACK_COLUMNS, "tracks", limits.max_boxes)
        return frame, TrackArrays(classes=tuple(frame.tracks.classes), **cols)
    except _Reject as r:
        return Rejection(
            r.reason, r.field, r.detail, _peek_int(obj, "seq"), _peek_int(obj, "stamp_ns")
        )
    except Exception as e:
        return Rejection(ErrorReason.INTERNAL_ERROR, None, f"{type(e).__name__}: {e}"[:300])


def decode_message(
    payload: bytes,
    model: type[M],
    limits: DecodeLimits = DecodeLimits(),
) -> M | Rejection:
    """Decode any other message (FrameError, ServiceStatus, SensorSnapshot)."""
    try:
        obj = _unpack(payload, limits)
        _check_version(obj)
        return _validate(model, obj)
    except _Reject as r:
        return Rejection(r.reason, r.field, r.detail)
    except Exception as e:
        return Rejection(ErrorReason.INTERNAL_ERROR, None, f"{type(e).__name__}: {e}"[:300])


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
) -> bytes:
    """A ``DetectionFrame`` from numpy columns (what a vehicle-side publisher calls)."""
    cols = BoxColumns.from_box_arrays(boxes)
    msg: dict[str, Any] = {
        "schema_version": SCHEMA_VERSION,
        "vehicle": vehicle,
        "sensor": sensor,
        "seq": int(seq),
        "stamp_ns": int(stamp_ns),
        "frame_id": frame_id,
        "key_frame": bool(key_frame),
        "boxes": cols.model_dump(mode="python", exclude_none=True),
    }
    if pose is not None:
        msg["pose"] = [float(v) for v in np.asarray(pose, dtype=np.float64).reshape(16)]
    return pack(msg)


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
    tracks: TrackArrays,
) -> bytes:
    columns: dict[str, Any] = {"count": len(tracks), "classes": list(tracks.classes)}
    for name, spec in TRACK_SPECS.items():
        columns[name] = to_column(getattr(tracks, name), spec)
    return pack(
        {
            "schema_version": SCHEMA_VERSION,
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
            "tracks": columns,
        }
    )
