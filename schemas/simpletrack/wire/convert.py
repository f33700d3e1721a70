"""The one adapter between the wire's columns and the core's types, both ways.

This is the only module of ``simpletrack.wire`` that imports ``simpletrack.core``: the rest of
the wire (and the client library on top of it) stays free of the tracker and scipy. Importing
it needs the service extra.

The core keeps a box as one (N, 7) float64 row in its measured-state order (``CENTER``,
``YAW``, ``SIZE`` of ``simpletrack.core.boxes``); the wire carries float32 ``center``, ``yaw``
and ``size`` columns and float64 scores. Class codes index a table of names on both sides;
-1 marks a class the caller ignores.
"""

from __future__ import annotations

import functools
import sys
from collections.abc import Sequence
from dataclasses import replace
from typing import TYPE_CHECKING

import msgpack
import numpy as np
import numpy.typing as npt

from simpletrack.core import jit
from simpletrack.core.boxes import CENTER, SIZE, YAW, Boxes
from simpletrack.core.frames import Frame, Tracks
from simpletrack.core.input_kernels import detection_extents as _detection_extents
from simpletrack.core.input_kernels import detection_rows
from simpletrack.core.lifecycle import TrackState, UpdateKind
from simpletrack.core.output_kernels import NON_FINITE_ORDER
from simpletrack.core.packing_kernels import COLUMN_ORDER, pack_columns
from simpletrack.wire.codec import pack
from simpletrack.wire.columns import (
    F32,
    F64,
    I32,
    I64,
    TRACK_COLUMNS_OF,
    BoxArrays,
    TrackArrays,
    covariance_from_upper,
    covariance_to_upper,
)
from simpletrack.wire.reasons import WireTrackState

if TYPE_CHECKING:
    from simpletrack.wire.codec import DecodedDetections

# Re-exported so that light modules (the client) can name the core types in annotations
# without importing the core themselves.
__all__ = [
    "Boxes",
    "Tracks",
    "boxes_from_wire",
    "boxes_to_wire",
    "detection_extents",
    "frame_from_wire",
    "pack_tracks_checked",
    "pack_vehicle_tracks_checked",
    "track_boxes_from_wire",
    "tracks_from_wire",
    "tracks_to_wire",
    "vehicle_tracks_to_wire",
    "wire_states",
]


def _params(center: F32, yaw: F32, size: F32) -> F64:
    params = np.empty((center.shape[0], 7), dtype=np.float64)
    params[:, CENTER] = center
    params[:, YAW] = yaw
    params[:, SIZE] = size
    return params


def _kept(boxes: Boxes) -> Boxes:
    keep = boxes.cls >= 0
    return boxes if keep.all() else boxes.take(keep)


# --- core -> wire -------------------------------------------------------------------------
def boxes_to_wire(boxes: Boxes, classes: Sequence[str]) -> BoxArrays:
    """Core ``Boxes`` (codes index ``classes``) as detection columns, in wire precision."""
    if len(boxes) and int(boxes.cls.max()) >= len(classes):
        raise ValueError(f"class code {int(boxes.cls.max())} has no name in {tuple(classes)}")
    p = boxes.params
    return BoxArrays(
        classes=tuple(classes),
        class_index=boxes.cls.astype(np.int32),
        center=p[:, CENTER].astype(np.float32),
        size=p[:, SIZE].astype(np.float32),
        yaw=p[:, YAW].astype(np.float32),
        score=boxes.score.astype(np.float64),
        velocity=None if boxes.velocity is None else boxes.velocity.astype(np.float32),
    )


# The codes below are what wire_states computes them from: CONFIRMED (1) shifted left by
# one when coasting (2), and any other state TENTATIVE (0).
assert (WireTrackState.TENTATIVE, WireTrackState.CONFIRMED, WireTrackState.COASTING) == (0, 1, 2)
_CONFIRMED = int(TrackState.CONFIRMED)


def wire_states(tracks: Tracks) -> I32:
    """``WireTrackState`` codes: a confirmed track not updated on this frame is coasting."""
    # Three numpy calls (np.where over enum scalars took 10 us a frame).
    confirmed = tracks.state == _CONFIRMED
    codes: I32 = np.left_shift(confirmed, tracks.time_since_update > 0, dtype=np.int32)
    return codes


def tracks_to_wire(tracks: Tracks, id_base: int, classes: tuple[str, ...]) -> TrackArrays:
    """A tracker's output as track columns; ids are offset by the sensor's ``id_base``.
    The covariance travels as its upper triangle (``columns.COVARIANCE_UPPER``)."""
    p = tracks.boxes.params
    cov = tracks.covariance
    return TrackArrays(
        classes=classes,
        id=tracks.ids + np.int64(id_base),
        class_index=tracks.boxes.cls.astype(np.int32),
        center=p[:, CENTER].astype(np.float32),
        size=p[:, SIZE].astype(np.float32),
        yaw=p[:, YAW].astype(np.float32),
        score=tracks.boxes.score.astype(np.float64),
        velocity=tracks.velocity.astype(np.float32),
        state=wire_states(tracks),
        hits=tracks.hits.astype(np.int32),
        age=tracks.age.astype(np.int32),
        time_since_update=tracks.time_since_update.astype(np.int32),
        covariance=None if cov is None else covariance_to_upper(cov),
        age_s=_f64(tracks.age_s),
        time_since_update_s=_f64(tracks.time_since_update_s),
    )


_NO_COVARIANCE = np.zeros((0, 6, 6))
_compiled: bool | None = None  # whether kernels run compiled (asked once)


def _kernels_compiled() -> bool:
    global _compiled
    if _compiled is None:
        _compiled = jit.compiled()
    return _compiled


def detection_extents(
    center: F32, size: F32, yaw: F32, score: F64, velocity: F32 | None, class_index: I32
) -> F64 | None:
    """The decoder's reductions of a detection frame's columns in one compiled call
    (core/input_kernels.py; ``decode_detection_frame``'s ``extents_of``); None when kernels
    run uncompiled: the decoder then reduces them one by one."""
    if not _kernels_compiled():
        return None
    return _detection_extents(
        center, size, yaw, score, _NO_VELOCITY if velocity is None else velocity, class_index
    )


_NO_VELOCITY = np.zeros((0, 2), np.float32)


def pack_tracks_checked(
    tracks: Tracks, id_base: int, classes: tuple[str, ...], schema_version: int
) -> tuple[bytes, tuple[str, int] | None] | None:
    """The ``tracks`` map of a TrackFrame of ``schema_version`` as msgpack bytes, in one
    compiled call (core/packing_kernels.py): what ``encode_track_frame`` writes for
    ``tracks_to_wire``'s columns, byte for byte, with the guard's look; or (b"", the first
    non-finite (column, row)). None when kernels run uncompiled, the tracks lack ages in
    seconds, for a version it does not know, or on a big-endian machine (the wire is
    little-endian): then the columns' way (``tracks_to_wire``)."""
    if (
        not _kernels_compiled()
        or tracks.age_s is None
        or tracks.time_since_update_s is None
        or schema_version not in TRACK_COLUMNS_OF
        or sys.byteorder != "little"
    ):
        return None
    boxes, cov = tracks.boxes, tracks.covariance
    packed, column, row = pack_columns(
        tracks.ids, id_base, boxes.params, boxes.score, boxes.cls, tracks.velocity,
        tracks.state, tracks.time_since_update, tracks.hits, tracks.age,
        _NO_COVARIANCE if cov is None else cov, cov is not None,
        tracks.age_s, tracks.time_since_update_s,
        _classes_entry(classes), _KEYS, _KEY_AT, _INCLUDE[schema_version, cov is not None],
    )  # fmt: skip
    if column >= 0:
        return b"", (NON_FINITE_ORDER[column], row)
    return packed.tobytes(), None


@functools.lru_cache(maxsize=64)
def _classes_entry(classes: tuple[str, ...]) -> npt.NDArray[np.uint8]:
    """The ``classes`` key and list, packed (a tracker's classes are fixed: packed once)."""
    packed = msgpack.packb("classes") + msgpack.packb(list(classes), use_bin_type=True)
    return np.frombuffer(packed, np.uint8).copy()  # writable: the kernel's type


_PACKED_KEYS = [msgpack.packb(name) for name in COLUMN_ORDER]
_KEYS = np.frombuffer(b"".join(_PACKED_KEYS), np.uint8).copy()
_KEY_AT = np.cumsum([0] + [len(k) for k in _PACKED_KEYS], dtype=np.int64)
# Which columns a message carries, by (version, covariance or not): those of the version's
# table, the optional covariance only where there is one.
_INCLUDE = {
    (version, has_cov): np.array(
        [
            any(c.name == name for c in specs) and (name != "covariance" or has_cov)
            for name in COLUMN_ORDER
        ]
    )
    for version, specs in TRACK_COLUMNS_OF.items()
    for has_cov in (False, True)
}


def pack_vehicle_tracks_checked(
    tracks: Tracks, existence: F64, sensor_stamp_ns: I64, classes: tuple[str, ...], sensors: int
) -> bytes | None:
    """The ``tracks`` map of a VehicleTrackFrame as msgpack bytes: a TrackFrame's columns in
    one compiled call (``pack_tracks_checked``), then ``existence`` and ``sensor_stamp_ns``
    (N, ``sensors``) after them, the map's size raised by two: what ``encode_vehicle_track_frame``
    writes for ``vehicle_tracks_to_wire``'s columns, byte for byte. None where
    ``pack_tracks_checked`` gives none, or finds NaN or inf, or ``existence`` holds one: then
    the columns' way (its guard names the column). ValueError for a misshapen column."""
    n = len(tracks.ids)
    stamps = np.ascontiguousarray(sensor_stamp_ns, dtype=np.int64)
    ex = np.ascontiguousarray(existence, dtype=np.float64)
    if stamps.shape != (n, sensors) or ex.shape != (n,):
        raise ValueError(
            f"existence {ex.shape} and sensor_stamp_ns {stamps.shape} must be ({n},) and "
            f"({n}, {sensors})"
        )
    packed = pack_tracks_checked(tracks, 0, classes, max(TRACK_COLUMNS_OF))
    if packed is None or packed[1] is not None or not np.isfinite(ex).all():
        return None
    body = packed[0]
    if body[0] == 0xDE:  # map 16
        entries, rest = int.from_bytes(body[1:3], "big"), body[3:]
    else:  # a fixmap
        entries, rest = body[0] & 0x0F, body[1:]
    entries += 2
    head = bytes([0x80 | entries]) if entries <= 15 else b"\xde" + entries.to_bytes(2, "big")
    return b"".join(
        (head, rest, _EXISTENCE_KEY, pack(ex.tobytes()), _STAMPS_KEY, pack(stamps.tobytes()))
    )


_EXISTENCE_KEY, _STAMPS_KEY = msgpack.packb("existence"), msgpack.packb("sensor_stamp_ns")


def vehicle_tracks_to_wire(
    tracks: Tracks, existence: F64, sensor_stamp_ns: I64, classes: tuple[str, ...]
) -> TrackArrays:
    """A vehicle's tracks (core/vehicle.py) as the columns of a VehicleTrackFrame."""
    return replace(
        tracks_to_wire(tracks, 0, classes),
        existence=existence.astype(np.float64),
        sensor_stamp_ns=sensor_stamp_ns.astype(np.int64),
    )


def _f64(values: F64 | None) -> F64 | None:
    return None if values is None else values.astype(np.float64)


# --- wire -> core -------------------------------------------------------------------------
def boxes_from_wire(arrays: BoxArrays, codes: I32 | None = None) -> Boxes:
    """Detection columns as float64 core ``Boxes``. ``codes`` (default: the frame's own
    ``class_index``) are the boxes' class codes in the tracker's table; boxes coded -1
    (ignored classes) are left out."""
    boxes = Boxes.from_arrays(
        _params(arrays.center, arrays.yaw, arrays.size),
        arrays.score,
        arrays.class_index if codes is None else codes,
        arrays.velocity,
    )
    return _kept(boxes)


def frame_from_wire(decoded: DecodedDetections, stamp: float) -> tuple[Frame, int]:
    """The tracker's frame of a decoded detection frame (``stamp`` in seconds) and how many
    boxes of ignored classes were left out."""
    arrays = decoded.boxes
    codes = arrays.class_index if decoded.codes is None else decoded.codes
    velocity = arrays.velocity
    # One compiled call for the rows the tracker takes (core/input_kernels.py).
    if _kernels_compiled():
        params, score, cls, vel = detection_rows(
            arrays.center,
            arrays.yaw,
            arrays.size,
            arrays.score,
            codes,
            _NO_VELOCITY if velocity is None else velocity,
        )
        boxes = Boxes(params, score, cls, None if velocity is None else vel)
        frame = Frame(boxes, stamp, pose=decoded.pose, key_frame=decoded.frame.key_frame)
        return frame, len(decoded.boxes) - len(boxes)
    # What boxes_from_wire builds, without Boxes.from_arrays's conversions: the decoder's
    # columns have the wire's dtypes already (score float64, codes int32, one row each).
    boxes = Boxes(
        _params(arrays.center, arrays.yaw, arrays.size),
        arrays.score,
        codes,
        None if velocity is None else velocity.astype(np.float64),
    )
    kept = np.flatnonzero(codes >= 0)
    if kept.size < len(boxes):
        boxes = boxes.take(kept)
    frame = Frame(boxes=boxes, stamp=stamp, pose=decoded.pose, key_frame=decoded.frame.key_frame)
    return frame, len(decoded.boxes) - len(boxes)


def track_boxes_from_wire(tracks: TrackArrays, classes: Sequence[str] | None = None) -> Boxes:
    """Track columns as core ``Boxes`` (float64, planar velocity); codes index ``classes``
    (default: the frame's own table). Tracks of classes missing from ``classes`` are left out."""
    codes = tracks.class_index.astype(np.int32)
    if classes is not None:
        remap = [classes.index(c) if c in classes else -1 for c in tracks.classes]
        codes = np.array(remap, dtype=np.int32)[codes]
    boxes = Boxes.from_arrays(
        _params(tracks.center, tracks.yaw, tracks.size),
        tracks.score,
        codes,
        tracks.velocity[:, :2],
    )
    return _kept(boxes)


def tracks_from_wire(tracks: TrackArrays) -> Tracks:
    """Track columns as the core's ``Tracks``, ids as sent. Coasting reads back as confirmed."""
    state = np.where(
        tracks.state == WireTrackState.TENTATIVE, TrackState.TENTATIVE, TrackState.CONFIRMED
    )
    # The wire does not say how a track was updated; "not updated this frame" is what matters.
    update = np.where(tracks.time_since_update == 0, UpdateKind.MATCHED, UpdateKind.COASTED)
    return Tracks(
        ids=tracks.id.astype(np.int64),
        boxes=Boxes.from_arrays(
            _params(tracks.center, tracks.yaw, tracks.size), tracks.score, tracks.class_index
        ),
        velocity=tracks.velocity.astype(np.float64),
        state=state.astype(np.int8),
        update=update.astype(np.int8),
        hits=tracks.hits.astype(np.int32),
        age=tracks.age.astype(np.int32),
        time_since_update=tracks.time_since_update.astype(np.int32),
        covariance=None if tracks.covariance is None else covariance_from_upper(tracks.covariance),
        age_s=_f64(tracks.age_s),
        time_since_update_s=_f64(tracks.time_since_update_s),
    )
