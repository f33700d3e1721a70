"""The reported tracks in the precision they are sent in, in one compiled call.

``track_columns`` is what ``simpletrack.wire.convert.tracks_to_wire`` computes with ~20 numpy
calls and the finite guard (server/finite.py) with eight reductions more: each column cast
(float32 boxes, velocities and covariances, int32 codes and counters, the ids offset), the
covariance's upper triangle, the wire's track states, and the first value that is NaN or
inf in the float columns, in the guard's column order. The casts are the same IEEE
conversions numpy makes (round to nearest), so the columns are bit-identical
(tests/wire/test_convert.py holds them equal to the numpy path's).
"""

from __future__ import annotations

import math

import numpy as np
import numpy.typing as npt

from simpletrack.core.jit import helper, kernel

__all__ = ["NON_FINITE_ORDER", "track_columns"]

F64 = npt.NDArray[np.float64]
F32 = npt.NDArray[np.float32]
I64 = npt.NDArray[np.int64]
I32 = npt.NDArray[np.int32]
I8 = npt.NDArray[np.int8]

# The float columns in the order the guard reads them (server/finite.py FLOAT_COLUMNS, a
# sensor's: no ``existence``); ``track_columns`` names the first non-finite by its index here.
NON_FINITE_ORDER = (
    "center",
    "size",
    "yaw",
    "score",
    "velocity",
    "covariance",
    "age_s",
    "time_since_update_s",
)
_CONFIRMED = 1  # lifecycle.TrackState.CONFIRMED
_X, _Y, _Z, _YAW, _L, _W, _H = range(7)  # boxes.CENTER, YAW, SIZE

_SIGNATURE = (
    "Tuple((int64[:], int32[:], float32[:, :], float32[:, :], float32[:], float64[:],"
    " float32[:, :], int32[:], int32[:], int32[:], int32[:], float32[:, :], float64[:],"
    " float64[:], int64, int64))"
    "(int64[:], int64, float64[:, :], float64[:], int32[:], float64[:, :], int8[:], int32[:],"
    " int32[:], int32[:], float64[:, :, :], boolean, float64[:], float64[:])"
)


@kernel(_SIGNATURE)
def track_columns(
    ids: I64,
    id_base: int,
    params: F64,
    score: F64,
    cls: I32,
    velocity: F64,
    state: I8,
    tsu: I32,
    hits: I32,
    age: I32,
    cov: F64,
    has_cov: bool,
    age_s: F64,
    tsu_s: F64,
) -> tuple[
    I64, I32, F32, F32, F32, F64, F32, I32, I32, I32, I32, F32, F64, F64, int, int
]:  # fmt: skip
    """The columns of ``n`` reported tracks: ids + ``id_base``, class codes, centre, size,
    yaw, score, velocity, state, hits, age, frames since update, the covariance's upper
    triangle (``(n, 21)``; ``(0, 21)`` without one), ages in seconds; then the index in
    ``NON_FINITE_ORDER`` of the first column holding NaN or inf and its first such row
    (C order), or (-1, -1)."""
    n = ids.shape[0]
    o_ids = np.empty(n, np.int64)
    o_cls = np.empty(n, np.int32)
    center = np.empty((n, 3), np.float32)
    size = np.empty((n, 3), np.float32)
    yaw = np.empty(n, np.float32)
    o_score = np.empty(n, np.float64)
    vel = np.empty((n, 3), np.float32)
    o_state = np.empty(n, np.int32)
    o_hits = np.empty(n, np.int32)
    o_age = np.empty(n, np.int32)
    o_tsu = np.empty(n, np.int32)
    upper = np.empty((n if has_cov else 0, 21), np.float32)
    o_age_s = np.empty(n, np.float64)
    o_tsu_s = np.empty(n, np.float64)
    for i in range(n):
        o_ids[i] = ids[i] + id_base
        o_cls[i] = cls[i]
        center[i, 0] = np.float32(params[i, _X])
        center[i, 1] = np.float32(params[i, _Y])
        center[i, 2] = np.float32(params[i, _Z])
        size[i, 0] = np.float32(params[i, _L])
        size[i, 1] = np.float32(params[i, _W])
        size[i, 2] = np.float32(params[i, _H])
        yaw[i] = np.float32(params[i, _YAW])
        o_score[i] = score[i]
        for k in range(3):
            vel[i, k] = np.float32(velocity[i, k])
        confirmed = state[i] == _CONFIRMED
        o_state[i] = (2 if tsu[i] > 0 else 1) if confirmed else 0
        o_hits[i] = hits[i]
        o_age[i] = age[i]
        o_tsu[i] = tsu[i]
        if has_cov:
            j = 0
            for r in range(6):
                for c in range(r, 6):
                    upper[i, j] = np.float32(cov[i, r, c])
                    j += 1
        o_age_s[i] = age_s[i]
        o_tsu_s[i] = tsu_s[i]
    column, row = _first_non_finite(center, size, yaw, o_score, vel, upper, o_age_s, o_tsu_s)
    return (
        o_ids, o_cls, center, size, yaw, o_score, vel, o_state, o_hits, o_age, o_tsu, upper,
        o_age_s, o_tsu_s, column, row,
    )  # fmt: skip


@helper
def _first_non_finite(
    center: F32,
    size: F32,
    yaw: F32,
    score: F64,
    vel: F32,
    upper: F32,
    age_s: F64,
    tsu_s: F64,
) -> tuple[int, int]:
    """(column index in NON_FINITE_ORDER, row) of the first NaN or inf, or (-1, -1)."""
    n = center.shape[0]
    for i in range(n):
        for k in range(3):
            if not math.isfinite(center[i, k]):
                return 0, i
    for i in range(n):
        for k in range(3):
            if not math.isfinite(size[i, k]):
                return 1, i
    for i in range(n):
        if not math.isfinite(yaw[i]):
            return 2, i
    for i in range(n):
        if not math.isfinite(score[i]):
            return 3, i
    for i in range(n):
        for k in range(3):
            if not math.isfinite(vel[i, k]):
                return 4, i
    for i in range(upper.shape[0]):
        for k in range(21):
            if not math.isfinite(upper[i, k]):
                return 5, i
    for i in range(n):
        if not math.isfinite(age_s[i]):
            return 6, i
    for i in range(n):
        if not math.isfinite(tsu_s[i]):
            return 7, i
    return -1, -1
