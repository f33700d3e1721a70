"""Columnar box layouts: which column holds which dtype and width, and numpy views of them.

Every column is a C-order, little-endian buffer carried as one msgpack ``bin``; row i of a
column of width k occupies bytes ``[i*k*itemsize, (i+1)*k*itemsize)``.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
import numpy.typing as npt

F32 = npt.NDArray[np.float32]
F64 = npt.NDArray[np.float64]
I32 = npt.NDArray[np.int32]
I64 = npt.NDArray[np.int64]


@dataclass(frozen=True, slots=True)
class ColumnSpec:
    name: str
    dtype: str  # numpy dtype string, always explicitly little-endian
    width: int  # values per row (1 = a plain vector)
    optional: bool = False
    finite: bool = False  # NaN/inf are rejected
    # One value per fused sensor in each row: the row's width is the message's number of
    # sensors, not ``width`` (which is then 1, so ``row_bytes`` is one value's).
    per_sensor: bool = False

    @property
    def row_bytes(self) -> int:
        return int(np.dtype(self.dtype).itemsize) * self.width

    def json_schema_extra(self) -> dict[str, Any]:  # JSON values, for the pydantic models
        shape: list[str | int] = ["count"] if self.width == 1 else ["count", self.width]
        if self.per_sensor:
            shape = ["count", "sensors"]
        # contentEncoding/contentMediaType: JSON Schema's own words for binary in a string
        # (base64 when a message is shown as JSON); x-dtype/x-shape: what the bytes hold.
        return {
            "contentEncoding": "base64",
            "contentMediaType": "application/octet-stream",
            "x-dtype": self.dtype,
            "x-shape": shape,
        }


def _f32(name: str, width: int, optional: bool = False) -> ColumnSpec:
    return ColumnSpec(name, "<f4", width, optional=optional, finite=True)


# Scores are float64: evaluations threshold on exact score values (KITTI's sAMOTA uses the
# scores themselves as thresholds), so float32 rounding on the wire would change results.
_SCORE = ColumnSpec("score", "<f8", 1, finite=True)


DETECTION_COLUMNS: tuple[ColumnSpec, ...] = (
    ColumnSpec("class_index", "<i4", 1),
    _f32("center", 3),
    _f32("size", 3),
    _f32("yaw", 1),
    _SCORE,
    _f32("velocity", 2, optional=True),
)

TRACK_COLUMNS_V1: tuple[ColumnSpec, ...] = (
    ColumnSpec("id", "<i8", 1),
    ColumnSpec("class_index", "<i4", 1),
    _f32("center", 3),
    _f32("size", 3),
    _f32("yaw", 1),
    _SCORE,
    _f32("velocity", 3),
    ColumnSpec("state", "<i4", 1),
    ColumnSpec("hits", "<i4", 1),
    ColumnSpec("age", "<i4", 1),
    ColumnSpec("time_since_update", "<i4", 1),
)
# TrackFrame version 2 adds these. The covariance is the upper triangle, row-major, of the
# symmetric 6x6 over [x, y, z, vx, vy, vz] (COVARIANCE_UPPER): 21 values, not 36, since
# the other 15 repeat them; absent when the motion model keeps none. Seconds are float64:
# they are differences of stamps, and a planner compares them with its own clock.
TRACK_COLUMNS_V2_ADDED: tuple[ColumnSpec, ...] = (
    _f32("covariance", 21, optional=True),
    ColumnSpec("age_s", "<f8", 1, finite=True),
    ColumnSpec("time_since_update_s", "<f8", 1, finite=True),
)
TRACK_COLUMNS: tuple[ColumnSpec, ...] = TRACK_COLUMNS_V1 + TRACK_COLUMNS_V2_ADDED
# The columns of each TrackFrame schema version (3 adds the epoch, which is not a column).
TRACK_COLUMNS_OF: dict[int, tuple[ColumnSpec, ...]] = {
    1: TRACK_COLUMNS_V1,
    2: TRACK_COLUMNS,
    3: TRACK_COLUMNS,
}
COVARIANCE_UPPER = np.triu_indices(6)  # (row, col) of each of the 21 values, in order
# A vehicle's fused tracks (VehicleTrackFrame): a TrackFrame version 2's columns and two more.
# sensor_stamp_ns is (count, len(sensors)): -1 where that sensor never updated the track.
VEHICLE_TRACK_COLUMNS: tuple[ColumnSpec, ...] = (
    *TRACK_COLUMNS,
    ColumnSpec("existence", "<f8", 1, finite=True),
    ColumnSpec("sensor_stamp_ns", "<i8", 1, per_sensor=True),
)

DETECTION_SPECS = {c.name: c for c in DETECTION_COLUMNS}
TRACK_SPECS = {c.name: c for c in TRACK_COLUMNS}
VEHICLE_TRACK_SPECS = {c.name: c for c in VEHICLE_TRACK_COLUMNS}


# Each of the 21 values' index in a row-major 6x6, in order.
_UPPER_FLAT = (COVARIANCE_UPPER[0] * 6 + COVARIANCE_UPPER[1]).astype(np.intp)


def covariance_to_upper(cov: npt.ArrayLike) -> F32:
    """(N, 6, 6) symmetric matrices as the (N, 21) float32 column."""
    a = np.asarray(cov)
    if a.ndim != 3 or a.shape[1:] != (6, 6):  # what the indexing below would say
        return np.ascontiguousarray(
            a[:, COVARIANCE_UPPER[0], COVARIANCE_UPPER[1]], dtype=np.float32
        )
    return a.reshape(a.shape[0], 36).take(_UPPER_FLAT, axis=1).astype(np.float32)


def covariance_from_upper(upper: npt.ArrayLike) -> F64:
    """The (N, 21) column as (N, 6, 6) float64 symmetric matrices."""
    u = np.asarray(upper, dtype=np.float64)
    out = np.zeros((u.shape[0], 6, 6))
    out[:, COVARIANCE_UPPER[0], COVARIANCE_UPPER[1]] = u
    out[:, COVARIANCE_UPPER[1], COVARIANCE_UPPER[0]] = u
    return out


def to_column(values: npt.ArrayLike, spec: ColumnSpec, sensors: int | None = None) -> bytes:
    """Pack an array as the column's little-endian buffer (shape-checked against the width;
    a per-sensor column against ``sensors``, which it needs)."""
    arr = np.ascontiguousarray(values, dtype=np.dtype(spec.dtype))
    if spec.per_sensor:
        if sensors is None:
            raise ValueError(f"column {spec.name} needs the number of sensors")
        if arr.ndim != 2 or arr.shape[1] != sensors:
            raise ValueError(f"column {spec.name} must have shape (N, {sensors}), got {arr.shape}")
        return arr.tobytes()
    if (spec.width == 1 and arr.ndim != 1) or (
        spec.width > 1 and (arr.ndim != 2 or arr.shape[1] != spec.width)
    ):
        want = "(N,)" if spec.width == 1 else f"(N, {spec.width})"
        raise ValueError(f"column {spec.name} must have shape {want}, got {arr.shape}")
    return arr.tobytes()


def view_column(buf: bytes, spec: ColumnSpec) -> npt.NDArray[np.generic]:
    """A read-only numpy view of a column whose byte length was already checked."""
    arr = np.frombuffer(buf, dtype=np.dtype(spec.dtype))
    return arr if spec.width == 1 else arr.reshape(-1, spec.width)


@dataclass(frozen=True, slots=True)
class BoxArrays:
    """Decoded detection boxes. ``class_index`` indexes ``classes`` (the frame's own table)."""

    classes: tuple[str, ...]
    class_index: I32
    center: F32  # (N, 3) x, y, z of the box centre
    size: F32  # (N, 3) l, w, h
    yaw: F32  # (N,)
    score: F64  # (N,)
    velocity: F32 | None = None  # (N, 2) vx, vy

    def __len__(self) -> int:
        return int(self.center.shape[0])

    def class_names(self) -> list[str]:
        return [self.classes[i] for i in self.class_index.tolist()]


@dataclass(frozen=True, slots=True)
class TrackArrays:
    """Decoded tracks. ``state`` holds ``WireTrackState`` codes. ``covariance``, ``age_s``
    and ``time_since_update_s`` come with TrackFrame version 2 (None from a version-1 frame;
    ``covariance`` also None when the service's motion model keeps none); ``existence`` and
    ``sensor_stamp_ns`` with a vehicle's fused tracks (VehicleTrackFrame) only."""

    classes: tuple[str, ...]
    id: I64
    class_index: I32
    center: F32
    size: F32
    yaw: F32
    score: F64
    velocity: F32  # (N, 3) vx, vy, vz
    state: I32
    hits: I32
    age: I32
    time_since_update: I32
    covariance: F32 | None = None  # (N, 21) upper triangle of [x, y, z, vx, vy, vz]
    age_s: F64 | None = None  # (N,) seconds from birth to this frame's stamp
    time_since_update_s: F64 | None = None  # (N,) seconds from the last update
    existence: F64 | None = None  # (N,) probability in [0, 1] that the track is an object
    # (N, S), S = len(VehicleTrackFrame.sensors): the stamp_ns of sensor j's last update of
    # track i, -1 when that sensor never updated it.
    sensor_stamp_ns: I64 | None = None

    def __len__(self) -> int:
        return int(self.id.shape[0])

    def covariance_matrices(self) -> F64 | None:
        """The covariance as (N, 6, 6) float64 matrices, or None when not sent."""
        return None if self.covariance is None else covariance_from_upper(self.covariance)
