"""An ordinary frame's whole step, compiled in one call.

``step_frame`` is ``Tracker.step`` after its argument checks for a frame whose every class
block is dense (core/pairs.py) and measured by the IoU family: the degenerate boxes dropped,
the NMS walk (``pair_kernels.nms_walk``), then: predict every track
(``kalman_kernels.predict_all``; ``motion_kernels.predict_models`` when a class has a motion
model or its own noise; or constant velocity), the predicted boxes, the stage-1 and stage-2
candidates, the distance table (``pair_kernels.class_table``) with the lost tracks' gate
(``revive_kernels``), stage 1
(``assignment_kernels.stage1_dense``), stage 2, then ``advance_kernels.advance``. It calls the
same kernels the staged path calls, with the same arguments, and does the glue between them
(thresholds, index lists, stage 2) with the same comparisons in the same order: its outputs
are bit-identical to the staged path's (tests/core/test_step_kernels.py runs both). What it
saves is the ~70 numpy calls and six kernel calls of Python around them (half of a warm
nuScenes step, and more of a cold one: the first frame after an idle spell).

The staged path (core/tracker.py) keeps everything else: gated frames, L2 and Mahalanobis
metrics, frames after a gap, and blocks without a finite assignment (``InfeasibleBlock``: the
staged path then raises scipy's error).
"""

from __future__ import annotations

import math

import numpy as np
import numpy.typing as npt

from simpletrack.core.advance_kernels import ADVANCE_OUTPUTS, advance
from simpletrack.core.assignment_kernels import INFEASIBLE, stage1_dense
from simpletrack.core.boxes import H, L, W
from simpletrack.core.jit import helper, kernel
from simpletrack.core.kalman_kernels import predict_all, wrap_once
from simpletrack.core.motion_kernels import predict_models
from simpletrack.core.pair_kernels import class_table, nms_walk
from simpletrack.core.revive_kernels import gate_dense, lost_tracks

__all__ = [
    "FAR_COST",
    "GATE_WIDENING",
    "HUNGARIAN",
    "MAX_AGE",
    "MAX_DISTANCE",
    "N_ASSOCIATION",
    "REVIVE_FRAMES",
    "REVIVE_GATE",
    "SCORE_HIGH",
    "SCORE_LOW",
    "STAGE2_MAX",
    "TWO_STAGE",
    "InfeasibleBlock",
    "step_frame",
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
    REVIVE_FRAMES,
    REVIVE_GATE,
) = range(12)
N_ASSOCIATION = 12

_COASTED, _MATCHED, _EXTENDED = 0, 1, 3  # lifecycle.UpdateKind
_YAW = 3

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
    " float64[:, :], float64[:], int32[:], float64[:, :], boolean, boolean, int64[:], float64[:],"
    " boolean, boolean, int64, int64, float64,"
    " float64[:, :], int64[:], boolean, float64, float64,"
    " float64[:, :], float64[:, :], float64[:, :, :], int64, float64, float64[:, :],"
    " boolean, int64[:], float64[:, :])"
)


@kernel(_STEP)
def step_frame(
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
    params: F64,
    det_score: F64,
    det_cls: I32,
    velocity: F64,
    has_velocity: bool,
    drop: bool,
    order: I64,
    nms_iou: F64,
    key: bool,
    kalman: bool,
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
    models: bool,
    model: I64,
    q_diag: F64,
) -> tuple[
    I64, I32, F64, F64, F64, F64, I32, I32, I32, I8, I8, F64, F64, F64,
    I64, F64, F64, I32, F64, I8, I8, I32, I32, I32, F64, F64, F64, int,
]:  # fmt: skip
    """``advance``'s 27 outputs (the next track table's columns, then the reported tracks),
    then the number of births, for an ordinary frame past ``Tracker.step``'s argument checks.
    The tracks are ``TrackTable.step_columns``; the detections as they came (``drop``: the
    degenerate ones are dropped here, as nms.drop_degenerate does), walked by NMS in
    ``order`` (or in the STABLE order when it is empty); ``velocity`` is (0, 2) without
    ``has_velocity``. ``assoc`` is the per-class association table (the columns above),
    ``options`` advance's; ``p0`` the births' covariance per class. ``models``: predict by
    the classes' motion models (``model``, ``q_diag``: motion_kernels.predict_models) instead
    of ``predict_all`` with ``q``. Raises InfeasibleBlock."""
    # Pre-processing (Tracker._preprocess).
    n = params.shape[0]
    keep = np.empty(n, dtype=np.int64)
    n_keep = 0
    for i in range(n):
        ok = True
        if drop:
            ok = math.isfinite(det_score[i])
            for c in range(7):
                ok = ok and math.isfinite(params[i, c])
            ok = ok and min(params[i, L], params[i, W], params[i, H]) > 0
            if has_velocity:
                ok = ok and math.isfinite(velocity[i, 0]) and math.isfinite(velocity[i, 1])
        if ok:
            keep[n_keep] = i
            n_keep += 1
    b_params, b_score, b_cls, b_vel = _rows(params, det_score, det_cls, velocity, keep[:n_keep])
    if order.size == 0 and n_keep > 0:
        # np.lexsort((-score, cls)): by class, then descending score, ties in input order.
        by_score = np.argsort(-b_score, kind="mergesort")
        order = by_score[np.argsort(b_cls[by_score], kind="mergesort")]
    b_cls64 = b_cls.astype(np.int64)
    kept = nms_walk(b_params, b_cls64, order, nms_iou, exact_vertical)
    d_params, d_score, d_cls, d_vel = _rows(b_params, b_score, b_cls, b_vel, kept)

    # C-ordered (views of C-ordered inputs, copies of strided ones): the kernels below are
    # compiled for these types and index them without strides (a third of the step); the
    # detections' columns are C-ordered copies already.
    x_c, p_c = np.ascontiguousarray(x), np.ascontiguousarray(p)
    n_t = ids.shape[0]
    n_d = d_params.shape[0]
    n_cls = assoc.shape[0]

    # Predict (Tracker._predict) and the predicted boxes (motion.predicted_boxes).
    dt = np.empty(n_t)
    for t in range(n_t):
        dt[t] = stamp - t_update[t]
    nx = x_c.shape[1]
    if kalman and models:
        x_pred, p_pred = predict_models(x_c, p_c, dt, cls, model, q_diag)
    elif kalman:
        x_pred, p_pred = predict_all(x_c, p_c, dt, q)
    else:
        x_pred = np.empty((n_t, nx))
        for t in range(n_t):
            for i in range(nx):
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
    pool_params = np.empty((n_pool, d_params.shape[1]))
    pool_cls = np.empty(n_pool, dtype=np.int64)
    row = np.full(n_d, -1, dtype=np.int64)
    cand = np.empty(n_cand, dtype=np.int64)
    cand_rows = np.empty(n_cand, dtype=np.int64)
    cand_cls = np.empty(n_cand, dtype=np.int64)
    k = 0
    h = 0
    for i in range(n_d):
        if is_high[i] or is_low[i]:
            pool_params[k] = d_params[i]
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
    # Lost tracks (revive_frames): their likelihood gate, and no stage-2 extension.
    if assoc[:, REVIVE_FRAMES].max() > 0.0:
        lost = lost_tracks(t_cls, tsu, state, assoc[:, REVIVE_FRAMES], assoc[:, MAX_AGE])
        gate_dense(
            table, pool_params, pool_cls, pred_box, p_pred, lost, t_cls, r,
            assoc[:, REVIVE_GATE], assoc[:, FAR_COST],
        )  # fmt: skip
    else:
        lost = np.zeros(n_t, dtype=np.bool_)

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
        if update[t] != _COASTED or (key and assoc[c, TWO_STAGE] == 0.0) or lost[t]:
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
        d_params, d_score, d_cls, d_vel,
        key, kalman, has_velocity, policy, frame_count, next_id,
        stamp, coast_decay, options, r, p0,
    )  # fmt: skip
    return out + (unmatched_det.shape[0],)  # noqa: RUF005 (numba types a tuple's +, not *)


@helper
def _rows(params: F64, score: F64, cls: I32, velocity: F64, rows: I64) -> tuple[F64, F64, I32, F64]:
    """Boxes.take: the listed rows of every column (velocity only when it has rows)."""
    n = rows.size
    out_p = np.empty((n, 7))
    out_s = np.empty(n)
    out_c = np.empty(n, dtype=np.int32)
    out_v = np.empty((n if velocity.shape[0] > 0 else 0, 2))
    for k in range(n):
        i = rows[k]
        out_p[k] = params[i]
        out_s[k], out_c[k] = score[i], cls[i]
        if out_v.shape[0] > 0:
            out_v[k] = velocity[i]
    return out_p, out_s, out_c, out_v
