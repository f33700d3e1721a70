"""The lost tracks of ``revive_frames`` (ImmortalTracker) and their likelihood gate, compiled.

A track is lost when its class has ``revive_frames``, it is confirmed, and it has missed
``max_age`` key frames or more: it is kept and predicted, never reported, and may be matched
again at stage 1. With ``revive_gate`` T, a pair of a lost track and a detection also needs

    d^2 + ln det(2 pi S) <= T,

d^2 the detection's bird's-eye centre's Mahalanobis distance from the prediction under
S = P_xy + R_xy. The left side is -2 ln of the track's likelihood for that centre; T is -2 ln
of a new object's density (per m^2). So a lost track claims a detection only where it
explains it better than a new object would, and as its prediction spreads (ln det S grows),
the radius it claims shrinks, to none: an old prediction does not take a new object's
detection. A pair that fails gets the class's far cost, which no threshold accepts (as a
widened gate's pairs beyond their reach do, core/tracker.py).
"""

from __future__ import annotations

import math

import numpy as np
import numpy.typing as npt

from simpletrack.core.jit import helper, kernel

F64 = npt.NDArray[np.float64]
I8 = npt.NDArray[np.int8]
I32 = npt.NDArray[np.int32]
I64 = npt.NDArray[np.int64]
B = npt.NDArray[np.bool_]

__all__ = ["gate_dense", "gate_pairs", "lost_tracks"]

_CONFIRMED = 1  # lifecycle.TrackState
_LOG_2PI_SQ = 2.0 * math.log(2.0 * math.pi)

_LOST = "boolean[::1](int64[:], int32[:], int8[:], float64[:], float64[:])"
_DENSE = (
    "void(float64[:, :], float64[:, :], int64[:], float64[:, :], float64[:, :, :],"
    " boolean[:], int64[:], float64[:, :], float64[:], float64[:])"
)
_PAIRS = (
    "boolean[::1](int64[:], int64[:], float64[:, :], float64[:, :], float64[:, :, :],"
    " float64[:, :], float64[:])"
)


@kernel(_LOST)
def lost_tracks(t_cls: I64, tsu: I32, state: I8, revive: F64, max_age: F64) -> B:
    """Which tracks are lost before this frame (``revive``, ``max_age``: per class)."""
    n = t_cls.shape[0]
    out = np.empty(n, dtype=np.bool_)
    for t in range(n):
        c = t_cls[t]
        out[t] = revive[c] > 0.0 and state[t] == _CONFIRMED and tsu[t] >= max_age[c]
    return out


@helper
def _claim(dx: float, dy: float, p: F64, r: F64) -> float:
    """d^2 + ln det(2 pi S) for the offset (dx, dy), S = P_xy + R_xy."""
    a = float(p[0, 0] + r[0, 0])
    b = float(p[0, 1] + r[0, 1])
    c = float(p[1, 0] + r[1, 0])
    d = float(p[1, 1] + r[1, 1])
    det = a * d - b * c
    if not det > 0.0:
        return math.inf
    d2 = (d * dx * dx - (b + c) * dx * dy + a * dy * dy) / det
    return d2 + _LOG_2PI_SQ + math.log(det)


@kernel(_DENSE)
def gate_dense(
    table: F64,
    d_params: F64,
    d_cls: I64,
    pred_box: F64,
    p_pred: F64,
    lost: B,
    t_cls: I64,
    r: F64,
    gate: F64,
    far: F64,
) -> None:
    """In place: each lost track's same-class pairs in the dense (detection, track) table
    that fail its class's ``gate`` (+inf: none) cost the class's ``far`` cost."""
    for t in range(lost.shape[0]):
        c = t_cls[t]
        if not lost[t] or not math.isfinite(gate[c]):
            continue
        for i in range(d_params.shape[0]):
            if d_cls[i] != c:
                continue
            dx = d_params[i, 0] - pred_box[t, 0]
            dy = d_params[i, 1] - pred_box[t, 1]
            if not _claim(dx, dy, p_pred[t], r) <= gate[c]:
                table[i, t] = far[c]


@kernel(_PAIRS)
def gate_pairs(
    rows: I64, cols: I64, d_params: F64, pred_box: F64, p_pred: F64, r: F64, gate: F64
) -> B:
    """For listed pairs of lost tracks (``cols``) and detections (``rows``): whether each
    passes the gate ``gate[k]`` (+inf: passes)."""
    out = np.empty(rows.shape[0], dtype=np.bool_)
    for k in range(rows.shape[0]):
        if not math.isfinite(gate[k]):
            out[k] = True
            continue
        i, t = rows[k], cols[k]
        dx = d_params[i, 0] - pred_box[t, 0]
        dy = d_params[i, 1] - pred_box[t, 1]
        out[k] = _claim(dx, dy, p_pred[t], r) <= gate[k]
    return out
