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

    @property
    def row_bytes(self) -> int:
        return int(np.dtype(self.dtype).itemsize) * self.width

    def json_schema_extra(self) -> dict[str, Any]:  # JSON values, for the pydantic models
        shape: list[str | int] = ["count"] if self.width == 1 else ["count", self.width]
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

TRACK_COLUMNS: tuple[ColumnSpec, ...] = (
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

DETECTION_SPECS = {c.name: c for c in DETECTION_COLUMNS}
TRACK_SPECS = {c.name: c for c in TRACK_COLUMNS}


def to_column(values: npt.ArrayLike, spec: ColumnSpec) -> bytes:
    """Pack an array as the column's little-endian buffer (shape-checked against the width)."""
    arr = np.ascontiguousarray(values, dtype=np.dtype(spec.dtype))
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
    """Decoded tracks. ``state`` holds ``WireTrackState`` codes."""

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

    def __len__(self) -> int:
        return int(self.id.shape[0])
