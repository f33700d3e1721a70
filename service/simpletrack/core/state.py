"""A tracker's tracks as parallel arrays (one row per live track), and their byte form."""

from __future__ import annotations

from dataclasses import dataclass, fields
from typing import Any

import msgpack
import numpy as np
import numpy.typing as npt

from simpletrack.core.motion import DIM_X


@dataclass(frozen=True, slots=True)
class TrackTable:
    ids: npt.NDArray[np.int64]
    cls: npt.NDArray[np.int32]
    x: npt.NDArray[np.float64]  # (T, X) state at the last filter update (X: 10 or 12)
    p: npt.NDArray[np.float64]  # (T, X, X) covariance at the last filter update
    t_update: npt.NDArray[np.float64]  # stamp of the last filter update
    score: npt.NDArray[np.float64]  # latest score (decays while coasting)
    hits: npt.NDArray[np.int32]
    age: npt.NDArray[np.int32]
    time_since_update: npt.NDArray[np.int32]
    state: npt.NDArray[np.int8]  # TrackState
    update: npt.NDArray[np.int8]  # UpdateKind of the latest frame
    out_box: npt.NDArray[np.float64]  # (T, 7) box reported for the latest frame
    # The score taken on the last stage-1 match (undecayed): what coast_output writes.
    match_score: npt.NDArray[np.float64]
    # Stamp of the frame the track was born on: its age in seconds (Tracks.age_s).
    t_birth: npt.NDArray[np.float64]

    @classmethod
    def empty(cls, dim: int = DIM_X) -> TrackTable:
        """No tracks, with states of ``dim`` (TrackerConfig.state_dim)."""
        return cls(
            ids=np.zeros(0, dtype=np.int64),
            cls=np.zeros(0, dtype=np.int32),
            x=np.zeros((0, dim)),
            p=np.zeros((0, dim, dim)),
            t_update=np.zeros(0),
            score=np.zeros(0),
            hits=np.zeros(0, dtype=np.int32),
            age=np.zeros(0, dtype=np.int32),
            time_since_update=np.zeros(0, dtype=np.int32),
            state=np.zeros(0, dtype=np.int8),
            update=np.zeros(0, dtype=np.int8),
            out_box=np.zeros((0, 7)),
            match_score=np.zeros(0),
            t_birth=np.zeros(0),
        )

    def __len__(self) -> int:
        return int(self.ids.shape[0])

    def step_columns(self) -> tuple[
        npt.NDArray[np.int64], npt.NDArray[np.int32], npt.NDArray[np.float64],
        npt.NDArray[np.float64], npt.NDArray[np.float64], npt.NDArray[np.float64],
        npt.NDArray[np.int32], npt.NDArray[np.int32], npt.NDArray[np.int32],
        npt.NDArray[np.int8], npt.NDArray[np.float64], npt.NDArray[np.float64],
    ]:  # fmt: skip
        """The columns a step starts from, in the compiled kernels' argument order (all but
        ``update`` and ``out_box``, which only the frame's own outcome sets)."""
        return (
            self.ids, self.cls, self.x, self.p, self.t_update, self.score, self.hits, self.age,
            self.time_since_update, self.state, self.match_score, self.t_birth,
        )  # fmt: skip

    def take(self, index: npt.ArrayLike) -> TrackTable:
        idx = np.asarray(index)
        return TrackTable(*(getattr(self, name)[idx] for name in _FIELDS))

    def concat(self, other: TrackTable) -> TrackTable:
        return TrackTable(
            *(np.concatenate([getattr(self, name), getattr(other, name)]) for name in _FIELDS)
        )

    def to_msgpack_obj(self, compact: bool) -> dict[str, Any]:
        """``compact``: a column's cells that are zero in every track are left out (most of
        a covariance: 16 of its 100 cells are ever set). The same arrays, bit for bit, come
        back; a reader from before compact states cannot read one (``Tracker.to_bytes``)."""
        return {name: pack_array(getattr(self, name), compact) for name in _FIELDS}

    @classmethod
    def from_msgpack_obj(cls, obj: dict[str, Any]) -> TrackTable:
        """Also reads a state written before a later column existed (``_ADDED``)."""
        missing = [name for name in _FIELDS if name not in obj and name not in _ADDED]
        if missing:
            raise ValueError(f"tracker state lacks {', '.join(missing)}")
        # In the dtypes the compiled step is typed for, whatever wrote the snapshot.
        return cls(
            *(
                unpack_array(obj[name if name in obj else _ADDED[name]]).astype(
                    _DTYPES[name], copy=False
                )
                for name in _FIELDS
            )
        )


_FIELDS = tuple(f.name for f in fields(TrackTable))
_DTYPES = {name: getattr(TrackTable.empty(), name).dtype for name in _FIELDS}
# Columns added after states were first written, each with the column an older state fills
# it from: the same format number then still reads every snapshot a deployment holds.
# A state without birth stamps counts a track's age in seconds from its last update: a lower
# bound, and exact again for every track born after the restore.
_ADDED = {"match_score": "score", "t_birth": "t_update"}


def pack_array(a: npt.NDArray[Any], compact: bool = False) -> dict[str, Any]:
    """An array as a msgpack map (dtype, shape, little-endian bytes). ``compact``: for a table of rows (2 or more dimensions), only the cells of a row that
    some row has a nonzero bit in (``cells``, indices into the flattened row); the others are
    +0.0 (or 0) in every row, which is how they come back."""
    a = np.ascontiguousarray(a)
    little = a.dtype.newbyteorder("<")
    out: dict[str, Any] = {"dtype": little.str, "shape": list(a.shape)}
    if compact and a.ndim >= 2 and a.shape[0] and a.dtype.itemsize in (1, 2, 4, 8):
        rows = a.reshape(a.shape[0], -1)
        # By bits, not by value: a -0.0 is kept (it equals 0.0 but is not all zero bits).
        cells = np.flatnonzero(rows.view(f"u{a.dtype.itemsize}").any(axis=0))
        # At least one cell, so that the data's length bounds the rows a reader allocates.
        cells = cells if cells.size else np.zeros(1, dtype=np.intp)
        if cells.size < rows.shape[1]:
            out["cells"] = cells.tolist()
            out["data"] = rows[:, cells].astype(little).tobytes()
            return out
    out["data"] = a.astype(little).tobytes()
    return out


def unpack_array(obj: dict[str, Any]) -> npt.NDArray[Any]:
    dtype = np.dtype(obj["dtype"])
    shape = [int(n) for n in obj["shape"]]
    cells = obj.get("cells")
    if cells is None:
        arr = np.frombuffer(obj["data"], dtype=dtype).reshape(shape)
        return arr.astype(dtype.newbyteorder("="))
    width = int(np.prod(shape[1:], dtype=np.int64)) if len(shape) >= 2 else 0
    index = np.asarray(cells, dtype=np.int64)
    if (
        len(shape) < 2
        or index.ndim != 1
        or index.size == 0
        or index[0] < 0
        or index[-1] >= width
        or np.any(np.diff(index) <= 0)
    ):
        raise ValueError(f"compact array of shape {shape} with cells {cells!r}")
    kept = np.frombuffer(obj["data"], dtype=dtype).reshape(shape[0], index.size)
    rows = np.zeros((shape[0], width), dtype=dtype.newbyteorder("="))
    rows[:, index] = kept
    return rows.reshape(shape)


def pack(obj: dict[str, Any]) -> bytes:
    return bytes(msgpack.packb(obj, use_bin_type=True))


def unpack(blob: bytes) -> dict[str, Any]:
    out = msgpack.unpackb(blob, raw=False)
    if not isinstance(out, dict):
        raise ValueError("tracker state must be a msgpack map")
    return out
