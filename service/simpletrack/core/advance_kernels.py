"""The rest of a frame after association, compiled in one call (``Tracker.step``'s tail).

``advance`` takes the tracks as they were, their prediction and this frame's association, and
returns the tracks after the frame and what the frame reports:

1. scores decayed (x coast_score_decay, or fused: minus score_decay, clipped at 0);
2. filter corrections: stage-1 matches with their detection, stage-2 extensions with their own
   prediction (Kalman: ``kalman_kernels.update_into``; constant velocity: the detection's box
   and velocity replace the prediction's);
3. matched scores (the detection's, or fused with the decayed one);
4. on a key frame: hits, ages, the life cycle (min_hits, max_age, delete_below,
   max_position_std; revive_frames keeps a confirmed track lost instead of dead),
   births of the unmatched detections (each with its class's P0), and the dead removed;
5. the output policy, with coast_output; a lost track is never reported.

Every step is the same scalar arithmetic, in the same order, as the numpy code it replaced:
outputs are bit-identical (tests/core/test_advance_kernels.py runs both ways).
"""

from __future__ import annotations

import math

import numpy as np
import numpy.typing as npt

from simpletrack.core.jit import inline, kernel
from simpletrack.core.kalman_kernels import update_into, wrap_once

__all__ = [
    "ADVANCE_OUTPUTS",
    "COAST_OUTPUT",
    "DELETE_BELOW",
    "FUSED",
    "MAX_AGE",
    "MAX_POSITION_STD",
    "MIN_HITS",
    "N_OPTIONS",
    "POLICY_NUSCENES",
    "POLICY_PAPER",
    "POLICY_REFERENCE",
    "REVIVE",
    "SCORE_DECAY",
    "advance",
    "policy_shows",
]

# Columns of the per-class option table (Tracker builds it once from its config).
FUSED, SCORE_DECAY, MIN_HITS, MAX_AGE, DELETE_BELOW, MAX_POSITION_STD, COAST_OUTPUT, REVIVE = range(
    8
)
N_OPTIONS = 8
# Output policies (config.OutputPolicy), as the kernel reads them.
POLICY_PAPER, POLICY_REFERENCE, POLICY_NUSCENES = range(3)


@inline
def policy_shows(policy: int, tentative: bool, confirmed: bool, matched: bool) -> bool:
    """Whether the output policy reports a track (before coasting and the lost rule)."""
    if policy == POLICY_NUSCENES:
        return True
    if policy == POLICY_REFERENCE:
        return tentative or (confirmed and matched)
    return confirmed and matched


# lifecycle.TrackState and UpdateKind codes (kernels cannot read enums).
_TENTATIVE, _CONFIRMED, _DEAD = 0, 1, 2
_COASTED, _MATCHED = 0, 1
_YAW = 3
_POS_VEL = (0, 1, 2, 7, 8, 9)  # frames.POS_VEL

F64 = npt.NDArray[np.float64]
I64 = npt.NDArray[np.int64]
I32 = npt.NDArray[np.int32]
I8 = npt.NDArray[np.int8]

_TABLE_OUT = (
    "int64[::1], int32[::1], float64[:, ::1], float64[:, :, ::1], float64[::1], float64[::1],"
    " int32[::1], int32[::1], int32[::1], int8[::1], int8[::1], float64[:, ::1], float64[::1],"
    " float64[::1]"
)
_TRACKS_OUT = (
    "int64[::1], float64[:, ::1], float64[::1], int32[::1], float64[:, ::1], int8[::1],"
    " int8[::1], int32[::1], int32[::1], int32[::1], float64[:, :, ::1], float64[::1],"
    " float64[::1]"
)
# What advance returns, as numba types (core/step_kernels.py returns it too).
ADVANCE_OUTPUTS = f"{_TABLE_OUT}, {_TRACKS_OUT}"
_ADVANCE = (
    f"Tuple(({ADVANCE_OUTPUTS}))"
    "(int64[:], int32[:], float64[:, :], float64[:, :, :], float64[:], float64[:], int32[:],"
    " int32[:], int32[:], int8[:], float64[:], float64[:],"
    " float64[:, :], float64[:, :, :], float64[:, :], int8[:],"
    " int64[:], int64[:], int64[:], int64[:],"
    " float64[:, :], float64[:], int32[:], float64[:, :],"
    " boolean, boolean, boolean, int64, int64, int64, float64, float64,"
    " float64[:, :], float64[:, :], float64[:, :, :])"
)


@kernel(_ADVANCE)
def advance(
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
    x_pred: F64,
    p_pred: F64,
    pred_box: F64,
    update: I8,
    matched_det: I64,
    matched_trk: I64,
    extended: I64,
    unmatched_det: I64,
    d_params: F64,
    d_score: F64,
    d_cls: I32,
    d_velocity: F64,
    key: bool,
    kalman: bool,
    has_velocity: bool,
    policy: int,
    frame_count: int,
    next_id: int,
    stamp: float,
    coast_decay: float,
    options: F64,
    r: F64,
    p0: F64,
) -> tuple[
    I64, I32, F64, F64, F64, F64, I32, I32, I32, I8, I8, F64, F64, F64,
    I64, F64, F64, I32, F64, I8, I8, I32, I32, I32, F64, F64, F64,
]:  # fmt: skip
    """The track table after this frame (TrackTable's 14 columns, in order), then the reported
    tracks: ids, boxes, scores, classes, velocities, states, updates, hits, ages,
    time_since_update, covariances over POS_VEL ((K, 6, 6); (0, 6, 6) without Kalman),
    age_s, time_since_update_s. ``update`` is this frame's UpdateKind per track; births (key
    frames only) take ids from ``next_id`` on, in ``unmatched_det``'s order."""
    n = ids.shape[0]
    nx = x.shape[1]  # 10, or 12 with motion models (core/motion_kernels.py)
    n_m = matched_trk.shape[0]
    n_c = n_m + extended.shape[0]

    s = np.empty(n)
    for t in range(n):
        c = cls[t]
        v = score[t] * coast_decay
        if options[c, FUSED] != 0.0:
            v = score[t] - options[c, SCORE_DECAY]
            if not (v >= 0.0 or v != v):  # np.maximum(v, 0.0): NaN stays NaN
                v = 0.0
        s[t] = v

    # Corrected rows: rows[k] is the k-th of matched_trk then extended; corr[t] = k, or -1.
    rows = np.empty(n_c, dtype=np.int64)
    corr = np.full(n, -1, dtype=np.int64)
    tu = t_update.copy()
    for k in range(n_c):
        t = matched_trk[k] if k < n_m else extended[k - n_m]
        rows[k] = t
        corr[t] = k
        tu[t] = stamp
    xo = np.empty((n_c, nx))
    po = np.empty((n_c, nx, nx))
    zc = np.empty((n_c, 7))
    for k in range(n_c):
        zc[k] = d_params[matched_det[k]] if k < n_m else pred_box[rows[k]]
    if kalman:
        xc = np.empty((n_c, nx))
        pc = np.empty((n_c, nx, nx))
        for k in range(n_c):
            xc[k] = x_pred[rows[k]]
            pc[k] = p_pred[rows[k]]
        update_into(xc, pc, zc, r, xo, po)
    else:  # the detection's box (and velocity) replace the prediction's; P is kept
        for k in range(n_c):
            t = rows[k]
            xo[k] = x_pred[t]
            xo[k, :7] = zc[k]
            xo[k, _YAW] = wrap_once(xo[k, _YAW])
            if has_velocity:
                xo[k, 7:9] = d_velocity[matched_det[k]] if k < n_m else x_pred[t, 7:9]
            po[k] = p[t]

    ms = match_score.copy()
    for k in range(n_m):
        t = matched_trk[k]
        sd = d_score[matched_det[k]]
        if options[cls[t], FUSED] != 0.0:
            s[t] = 1.0 - (1.0 - sd) * (1.0 - s[t])
        else:
            s[t] = sd
        ms[t] = s[t]

    hi = hits.copy()
    ag = age.copy()
    ts = tsu.copy()
    st = state.copy()
    if key:
        for t in range(n):
            c = cls[t]
            ag[t] += 1
            ts[t] += 1
            if update[t] != _COASTED:
                hi[t] += 1
                ts[t] = 0
            min_hits = options[c, MIN_HITS]
            promote = st[t] == _TENTATIVE and (hi[t] >= min_hits or frame_count <= min_hits)
            if promote:
                st[t] = _CONFIRMED
            elif ts[t] >= options[c, MAX_AGE] + (
                options[c, REVIVE] if st[t] == _CONFIRMED else 0.0
            ):
                st[t] = _DEAD  # a confirmed track with revive_frames is lost in between
            if st[t] == _CONFIRMED and s[t] < options[c, DELETE_BELOW]:
                st[t] = _DEAD
            limit = options[c, MAX_POSITION_STD]
            std = np.sqrt(p_pred[t, 0, 0] + p_pred[t, 1, 1]) if math.isfinite(limit) else 0.0
            if update[t] != _MATCHED and std > limit:
                st[t] = _DEAD

    n_born = unmatched_det.shape[0] if key else 0
    alive = np.empty(n, dtype=np.bool_)
    n_alive = 0
    for t in range(n):
        alive[t] = not key or st[t] != _DEAD
        if alive[t]:
            n_alive += 1
    m = n_alive + n_born
    o_ids = np.empty(m, dtype=np.int64)
    o_cls = np.empty(m, dtype=np.int32)
    o_x = np.empty((m, nx))
    o_p = np.empty((m, nx, nx))
    o_tu = np.empty(m)
    o_s = np.empty(m)
    o_hi = np.empty(m, dtype=np.int32)
    o_ag = np.empty(m, dtype=np.int32)
    o_ts = np.empty(m, dtype=np.int32)
    o_st = np.empty(m, dtype=np.int8)
    o_up = np.empty(m, dtype=np.int8)
    o_ob = np.empty((m, 7))
    o_ms = np.empty(m)
    o_tb = np.empty(m)
    src = np.empty(m, dtype=np.int64)  # each row's track before this frame; -1: born now
    j = 0
    for t in range(n):
        if not alive[t]:
            continue
        src[j] = t
        o_ids[j], o_cls[j], o_tu[j], o_s[j] = ids[t], cls[t], tu[t], s[t]
        o_hi[j], o_ag[j], o_ts[j], o_st[j], o_up[j] = hi[t], ag[t], ts[t], st[t], update[t]
        k = corr[t]
        if k >= 0:
            o_x[j] = xo[k]
            o_p[j] = po[k]
            o_ob[j] = xo[k, :7]
        else:
            o_x[j] = x[t]
            o_p[j] = p[t]
            o_ob[j] = pred_box[t]
        o_ms[j], o_tb[j] = ms[t], t_birth[t]
        j += 1
    for b in range(n_born):
        u = unmatched_det[b]
        c = d_cls[u]
        min_hits = options[c, MIN_HITS]
        src[j] = -1
        o_ids[j] = next_id + b
        o_cls[j] = c
        o_x[j] = 0.0
        o_x[j, :7] = d_params[u]
        if kalman:
            o_p[j] = p0[c]
        else:
            o_p[j] = 0.0
            if has_velocity:
                o_x[j, 7:9] = d_velocity[u]
        o_tu[j] = stamp
        o_s[j] = d_score[u]
        o_hi[j], o_ag[j], o_ts[j] = 1, 0, 0
        o_st[j] = _CONFIRMED if (min_hits == 0 or frame_count <= min_hits) else _TENTATIVE
        o_up[j] = _MATCHED
        o_ob[j] = d_params[u]
        o_ms[j] = d_score[u]
        o_tb[j] = stamp
        j += 1

    keep = np.empty(m, dtype=np.bool_)
    coast = np.empty(m, dtype=np.bool_)
    k_out = 0
    for j in range(m):
        matched = o_up[j] == _MATCHED
        confirmed = o_st[j] == _CONFIRMED
        kp = policy_shows(policy, o_st[j] == _TENTATIVE, confirmed, matched)
        c = o_cls[j]
        if options[c, REVIVE] > 0.0 and o_ts[j] >= options[c, MAX_AGE]:
            kp = False  # lost: reported again once re-matched
        window = options[o_cls[j], COAST_OUTPUT]
        coast[j] = confirmed and not matched and window > 0 and o_ts[j] <= window
        keep[j] = kp or coast[j]
        if keep[j]:
            k_out += 1
    r_ids = np.empty(k_out, dtype=np.int64)
    r_box = np.empty((k_out, 7))
    r_s = np.empty(k_out)
    r_cls = np.empty(k_out, dtype=np.int32)
    r_vel = np.empty((k_out, 3))
    r_st = np.empty(k_out, dtype=np.int8)
    r_up = np.empty(k_out, dtype=np.int8)
    r_hi = np.empty(k_out, dtype=np.int32)
    r_ag = np.empty(k_out, dtype=np.int32)
    r_ts = np.empty(k_out, dtype=np.int32)
    r_cov = np.empty((k_out if kalman else 0, 6, 6))
    r_age_s = np.empty(k_out)
    r_tsu_s = np.empty(k_out)
    i = 0
    for j in range(m):
        if not keep[j]:
            continue
        r_ids[i], r_cls[i], r_st[i], r_up[i] = o_ids[j], o_cls[j], o_st[j], o_up[j]
        r_hi[i], r_ag[i], r_ts[i] = o_hi[j], o_ag[j], o_ts[j]
        r_box[i] = o_ob[j]
        r_s[i] = o_ms[j] if coast[j] else o_s[j]
        r_vel[i] = o_x[j, 7:10]
        if kalman:  # the covariance of the box reported: corrected, else predicted
            t = src[j]
            for a in range(6):
                for b in range(6):
                    ia, ib = _POS_VEL[a], _POS_VEL[b]
                    if t < 0:
                        r_cov[i, a, b] = o_p[j, ia, ib]
                    elif corr[t] >= 0:
                        r_cov[i, a, b] = po[corr[t], ia, ib]
                    else:
                        r_cov[i, a, b] = p_pred[t, ia, ib]
        r_age_s[i] = stamp - o_tb[j]
        r_tsu_s[i] = stamp - o_tu[j]
        i += 1
    return (
        o_ids, o_cls, o_x, o_p, o_tu, o_s, o_hi, o_ag, o_ts, o_st, o_up, o_ob, o_ms, o_tb,
        r_ids, r_box, r_s, r_cls, r_vel, r_st, r_up, r_hi, r_ag, r_ts, r_cov, r_age_s, r_tsu_s,
    )  # fmt: skip
