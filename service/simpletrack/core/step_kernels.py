"""An ordinary frame's whole step after pre-processing, compiled in one call.

``step_dense`` is ``Tracker.step`` from the prediction to the output for a frame whose every
class block is dense (core/pairs.py) and measured by the IoU family: predict every track
(``kalman_kernels.predict_all``, or constant velocity), the predicted boxes, the stage-1 and
stage-2 candidates, the distance table (``pair_kernels.class_table``), stage 1
(``assignment_kernels.stage1_dense``), stage 2, then ``advance_kernels.advance``. It calls the
same kernels the staged path calls, with the same arguments, and does the glue between them
(thresholds, index lists, stage 2) with the same comparisons in the same order: its outputs
are bit-identical to the staged path's (tests/core/test_step_kernels.py runs both). What it
saves is the ~60 numpy calls and five kernel calls of Python around them (a third of a warm
nuScenes step, and more of a cold one: the first frame after an idle spell).

The staged path (core/tracker.py) keeps everything else: gated frames, L2 and Mahalanobis
metrics, frames after a gap, and blocks without a finite assignment (``InfeasibleBlock``: the
staged path then raises scipy's error).
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt

from simpletrack.core.advance_kernels import ADVANCE_OUTPUTS, advance
from simpletrack.core.assignment_kernels import INFEASIBLE, stage1_dense
from simpletrack.core.jit import kernel
from simpletrack.core.kalman_kernels import predict_all, wrap_once
from simpletrack.core.pair_kernels import class_table

__all__ = [
    "FAR_COST",
    "GATE_WIDENING",
    "HUNGARIAN",
    "MAX_AGE",
    "MAX_DISTANCE",
    "N_ASSOCIATION",
    "SCORE_HIGH",
    "SCORE_LOW",
    "STAGE2_MAX",
    "TWO_STAGE",
    "InfeasibleBlock",
    "step_dense",
]

# Columns of the per-class association table (Tracker builds it once from its config);
# flags are 0.0 or 1.0, MAX_AGE an integer.
(
    SCORE_HIGH,
    SCORE_LOW,
    TWO_STAGE,
    STAGE2_MAX,
    MAX_DISTANCE,
    GATE_WIDENING,
    MAX_AGE,
    FAR_COST,
    HUNGARIAN,
    WIDENED,
) = range(10)
N_ASSOCIATION = 10

_COASTED, _MATCHED, _EXTENDED = 0, 1, 3  # lifecycle.UpdateKind
_YAW = 3
_X = 10

F64 = npt.NDArray[np.float64]
I64 = npt.NDArray[np.int64]
I32 = npt.NDArray[np.int32]
I8 = npt.NDArray[np.int8]


class InfeasibleBlock(ValueError):
    """A Hungarian block without a finite full assignment: the staged path raises scipy's
    error for it."""


_STEP = (
    f"Tuple(({ADVANCE_OUTPUTS}, int64))"
    "(int64[:], int32[:], float64[:, :], float64[:, :, :], float64[:], float64[:], int32[:],"
    " int32[:], int32[:], int8[:], float64[:], float64[:],"
    " float64[:, :], float64[:], int32[:], float64[:, :],"
    " boolean, boolean, boolean, int64, int64, float64,"
    " float64[:, :], int64[:], boolean, float64, float64,"
    " float64[:, :], float64[:, :], float64[:, :], int64, float64, float64[:, :])"
)


@kernel(_STEP)
def step_dense(
    ids: I64,
    cls: I32,
    x: F64,
    p: F64,
    t_update: F64,
    score: F64,
    hits: I32,
    age: I32,
    tsu: I32,
    state: I8,
    match_score: F64,
    t_birth: F64,
    d_params: F64,
    d_score: F64,
    d_cls: I32,
    d_velocity: F64,
    key: bool,
    kalman: bool,
    has_velocity: bool,
    frame_count: int,
    next_id: int,
    stamp: float,
    assoc: F64,
    overlap_kind: I64,
    exact_vertical: bool,
    non_key_high: float,
    non_key_low: float,
    q: F64,
    r: F64,
    p0: F64,
    policy: int,
    coast_decay: float,
    options: F64,
) -> tuple[
    I64, I32, F64, F64, F64, F64, I32, I32, I32, I8, I8, F64, F64, F64,
    I64, F64, F64, I32, F64, I8, I8, I32, I32, I32, F64, F64, F64, int,
]:  # fmt: skip
    """``advance``'s 27 outputs (the next track table's columns, then the reported tracks),
    then the number of births. The tracks are TrackTable's first 12 columns; the detections
    are pre-processed (NMS, world frame); ``assoc`` is the per-class association table (the
    columns above), ``options`` advance's. Raises InfeasibleBlock."""
    # C-ordered (views of C-ordered inputs, copies of strided ones): the kernels below are
    # compiled for these types and index them without strides (a third of the step).
    x_c, p_c = np.ascontiguousarray(x), np.ascontiguousarray(p)
    params_c, velocity_c = np.ascontiguousarray(d_params), np.ascontiguousarray(d_velocity)
    n_t = ids.shape[0]
    n_d = params_c.shape[0]
    n_cls = assoc.shape[0]

    # Predict (Tracker._predict) and the predicted boxes (motion.predicted_boxes).
    dt = np.empty(n_t)
    for t in range(n_t):
        dt[t] = stamp - t_update[t]
    if kalman:
        x_pred, p_pred = predict_all(x_c, p_c, dt, q)
    else:
        x_pred = np.empty((n_t, _X))
        for t in range(n_t):
            for i in range(_X):
                x_pred[t, i] = x_c[t, i] + x_c[t, i + 7] * dt[t] if i < 3 else x_c[t, i]
        p_pred = p_c
    pred_box = np.empty((n_t, 7))
    for t in range(n_t):
        for i in range(7):
            pred_box[t, i] = x_pred[t, i]
        pred_box[t, _YAW] = wrap_once(x_pred[t, _YAW])

    # Candidates: stage 1 over the high threshold, stage 2 over the low one; the pool of
    # either is the table's rows, in detection order.
    is_high = np.empty(n_d, dtype=np.bool_)
    is_low = np.empty(n_d, dtype=np.bool_)
    n_pool = 0
    n_cand = 0
    for i in range(n_d):
        c = d_cls[i]
        if key:
            is_high[i] = d_score[i] >= assoc[c, SCORE_HIGH]
            is_low[i] = d_score[i] > assoc[c, SCORE_LOW] and assoc[c, TWO_STAGE] != 0.0
        else:
            is_high[i] = d_score[i] >= non_key_high
            is_low[i] = d_score[i] > non_key_low
        if is_high[i] or is_low[i]:
            n_pool += 1
        if is_high[i]:
            n_cand += 1
    pool_params = np.empty((n_pool, params_c.shape[1]))
    pool_cls = np.empty(n_pool, dtype=np.int64)
    row = np.full(n_d, -1, dtype=np.int64)
    cand = np.empty(n_cand, dtype=np.int64)
    cand_rows = np.empty(n_cand, dtype=np.int64)
    cand_cls = np.empty(n_cand, dtype=np.int64)
    k = 0
    h = 0
    for i in range(n_d):
        if is_high[i] or is_low[i]:
            pool_params[k] = params_c[i]
            pool_cls[k] = d_cls[i]
            row[i] = k
            k += 1
        if is_high[i]:
            cand[h], cand_rows[h], cand_cls[h] = i, row[i], d_cls[i]
            h += 1
    t_cls = np.empty(n_t, dtype=np.int64)
    for t in range(n_t):
        t_cls[t] = cls[t]
    table = class_table(pool_params, pool_cls, pred_box, t_cls, overlap_kind, exact_vertical)

    # Stage 1 (Tracker._stage1 and _stage1_reach): the classes present, ascending.
    reach = np.empty(n_t)
    for t in range(n_t):
        c = t_cls[t]
        coasted = min(np.int64(tsu[t]), np.int64(assoc[c, MAX_AGE]))
        reach[t] = assoc[c, MAX_DISTANCE] + assoc[c, GATE_WIDENING] * coasted
    present = np.zeros(n_cls, dtype=np.int64)
    for a in range(n_cand):
        present[cand_cls[a]] += 1
    for t in range(n_t):
        present[t_cls[t]] += 1
    codes = np.flatnonzero(present)
    hungarian = assoc[:, HUNGARIAN] != 0.0
    widened = assoc[:, WIDENED] != 0.0
    matched_det, matched_trk, unmatched_det, status = stage1_dense(
        table,
        codes,
        cand,
        cand_rows,
        cand_cls,
        t_cls,
        assoc[:, MAX_DISTANCE].copy(),
        hungarian,
        widened,
        reach,
        assoc[:, FAR_COST].copy(),
    )
    if status == INFEASIBLE:
        raise InfeasibleBlock("a Hungarian block has no finite full assignment")

    # Stage 2 (Tracker._stage2): coasting tracks some low-score detection agrees with.
    update = np.full(n_t, _COASTED, dtype=np.int8)
    for a in range(matched_trk.shape[0]):
        update[matched_trk[a]] = _MATCHED
    extended = np.empty(n_t, dtype=np.int64)
    n_ext = 0
    for t in range(n_t):
        c = t_cls[t]
        if update[t] != _COASTED or (key and assoc[c, TWO_STAGE] == 0.0):
            continue
        limit = assoc[c, STAGE2_MAX]
        for i in range(n_d):
            if is_low[i] and table[row[i], t] <= limit:
                extended[n_ext] = t
                n_ext += 1
                break
    extended = extended[:n_ext].copy()
    for a in range(n_ext):
        update[extended[a]] = _EXTENDED

    out = advance(
        ids, cls, x_c, p_c, t_update, score, hits, age, tsu, state, match_score, t_birth,
        x_pred, p_pred, pred_box, update,
        matched_det, matched_trk, extended, unmatched_det,
        params_c, d_score, d_cls, velocity_c,
        key, kalman, has_velocity, policy, frame_count, next_id,
        stamp, coast_decay, options, r, p0,
    )  # fmt: skip
    return out + (unmatched_det.shape[0],)  # noqa: RUF005 (numba types a tuple's +, not *)
