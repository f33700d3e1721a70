"""A fused vehicle's per-frame bookkeeping, compiled (core/vehicle.py: the step's starting
counters, ``_columns``, and ``_report``'s rows and gather).

Each was numpy over the vehicle's ~100-200 tracks: some forty calls, every one costing more
than its arithmetic, a third of a fused frame's time in the service (docs/BENCHMARKS.md,
"Fused vehicles"). Here each is one loop over the tracks with the same operations in the same
order (additions, comparisons, copies), so the results are the numpy code's bit for bit; the
logarithms and exponentials stay in numpy, outside (``evidence`` comes in computed).
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt

from simpletrack.core.advance_kernels import policy_shows
from simpletrack.core.boxes import YAW
from simpletrack.core.frames import POS_VEL
from simpletrack.core.jit import kernel
from simpletrack.core.kalman_kernels import wrap_once

F64 = npt.NDArray[np.float64]
I8 = npt.NDArray[np.int8]
I32 = npt.NDArray[np.int32]
I64 = npt.NDArray[np.int64]
B = npt.NDArray[np.bool_]

__all__ = ["counter_in", "fused_columns", "report_gather", "report_rows"]

_COASTED, _MATCHED = 0, 1  # lifecycle.UpdateKind
_TENTATIVE, _CONFIRMED = 0, 1  # lifecycle.TrackState
_BOX = 7  # a box's parameters: a state's first seven values (motion.DIM_Z)

_COLUMNS = (
    "Tuple((int32[:, ::1], int64[:, ::1], int8[::1], float64[::1], int32[::1]))"
    "(int32[:, :], int64[:, :], int8[:], float64[:], int32[:], boolean[:], int64[:],"
    " int64[:], boolean[:], int8[:], float64[:], int64, boolean, int64, float64, float64)"
)
_REPORT = (
    "Tuple((int8[::1], boolean[::1], boolean[::1], boolean[::1], int64[::1], boolean[::1]))"
    "(int64[:], int8[:], int64[:], int32[:], int64[:, :], int8[:], int64, int8[:], int32[:],"
    " int64[:], int32[:], float64[:], int64, boolean, float64)"
)


@kernel(_COLUMNS)
def fused_columns(
    b_misses: I32,
    b_stamps: I64,
    b_kind: I8,
    b_odds: F64,
    b_occluded: I32,
    b_hidden: B,
    b_ids: I64,
    ids: I64,
    born: B,
    update: I8,
    evidence: F64,
    s: int,
    key_frame: bool,
    stamp_ns: int,
    miss_log_odds: float,
    logit_max: float,
) -> tuple[I32, I64, I8, F64, I32]:
    """(misses, stamps, last kind, log odds, occluded) of the tracks in view after a frame of
    sensor ``s``: ``ids`` (sorted), ``born`` and ``update`` the step's table; ``b_*`` the
    same tracks before it (``b_ids`` sorted); ``evidence`` the log odds of each row's match
    score as the sensor's evidence; ``miss_log_odds`` what a key frame's miss adds."""
    n, n_s = ids.shape[0], b_misses.shape[1]
    n0 = b_ids.shape[0]
    misses = np.full((n, n_s), -1, dtype=np.int32)
    stamps = np.full((n, n_s), -1, dtype=np.int64)
    kind = np.full(n, _MATCHED, dtype=np.int8)
    odds = np.zeros(n)
    occluded = np.zeros(n, dtype=np.int32)
    pos = np.searchsorted(b_ids, ids)
    top = max(n0 - 1, 0)
    for i in range(n):
        if born[i]:
            misses[i, s] = 0
            stamps[i, s] = stamp_ns
            odds[i] = evidence[i]
        else:
            p = min(pos[i], top)
            hidden = False
            if n0:
                misses[i] = b_misses[p]
                stamps[i] = b_stamps[p]
                kind[i] = b_kind[p]
                odds[i] = b_odds[p]
                occluded[i] = b_occluded[p]
                hidden = b_hidden[p]
            u = update[i]
            if u != _COASTED:  # updated
                occluded[i] = 0
                if key_frame:
                    misses[i, :] = -1
                    misses[i, s] = 0
                stamps[i, s] = stamp_ns
                kind[i] = u
                if u == _MATCHED:
                    odds[i] += evidence[i]
            elif not hidden:  # coasted in view
                occluded[i] = 0
                if key_frame:
                    misses[i, s] = max(misses[i, s], 0) + 1
                    odds[i] += miss_log_odds
            elif key_frame:  # coasted, hidden
                occluded[i] += 1
        x = odds[i]
        if x < -logit_max:
            odds[i] = -logit_max
        elif x > logit_max:
            odds[i] = logit_max
    return misses, stamps, kind, odds, occluded


@kernel(_REPORT)
def report_rows(
    out_ids: I64,
    out_update: I8,
    ids: I64,
    tsu: I32,
    stamps: I64,
    last_kind: I8,
    s: int,
    state: I8,
    cls: I32,
    coast_window: I64,
    occluded: I32,
    log_odds: F64,
    policy: int,
    doubt: bool,
    min_log_odds: float,
) -> tuple[I8, B, B, B, I64, B]:
    """(kind, fresh, coasting, reported, row of ``out``, in the step) of each track of the
    vehicle's table (``ids``), after a step that reported ``out_ids``: see
    ``VehicleTracker._report``. ``doubt``: a tentative track under ``min_log_odds`` is not
    reported."""
    n, m, n_s = ids.shape[0], out_ids.shape[0], stamps.shape[1]
    order = np.argsort(out_ids, kind="mergesort")
    sorted_ids = out_ids[order]
    kind = np.empty(n, dtype=np.int8)
    fresh = np.empty(n, dtype=np.bool_)
    coast = np.empty(n, dtype=np.bool_)
    keep = np.empty(n, dtype=np.bool_)
    where = np.zeros(n, dtype=np.int64)
    in_step = np.zeros(n, dtype=np.bool_)
    top = max(m - 1, 0)
    for i in range(n):
        k = np.int8(_COASTED)
        if m:
            w = order[min(np.searchsorted(sorted_ids, ids[i]), top)]
            where[i] = w
            if out_ids[w] == ids[i]:
                in_step[i] = True
                k = out_update[w]
        others = -1
        for j in range(n_s):
            if j != s and stamps[i, j] > others:
                others = stamps[i, j]
        if tsu[i] == 0 and k == _COASTED and (not in_step[i] or others > stamps[i, s]):
            k = last_kind[i]
        kind[i] = k
        f = k == _MATCHED
        confirmed = state[i] == _CONFIRMED
        window = coast_window[cls[i]]
        c = confirmed and not f and window > 0 and tsu[i] <= window
        r = policy_shows(policy, state[i] == _TENTATIVE, confirmed, f)
        r = (r or c) and (f or occluded[i] == 0)
        if doubt and log_odds[i] < min_log_odds and state[i] == _TENTATIVE:
            r = False
        fresh[i], coast[i], keep[i] = f, c, r
    return kind, fresh, coast, keep, where, in_step


_GATHER = (
    "Tuple((float64[:, ::1], float64[:, :, ::1], float64[::1], float64[:, ::1], float64[::1],"
    " float64[::1]))"
    "(int64[:], boolean[:], int64[:], float64[:, :], float64[:, :, :], float64[:, :],"
    " float64[:, :, :], boolean, boolean[:], boolean[:], float64[:], float64[:], float64[:, :],"
    " float64, float64[:], float64[:])"
)


@kernel(_GATHER)
def report_gather(
    rows: I64,
    in_step: B,
    where: I64,
    out_params: F64,
    out_cov: F64,
    x_away: F64,
    p_away: F64,
    kalman: bool,
    fresh: B,
    coast: B,
    match_score: F64,
    score: F64,
    x: F64,
    t: float,
    t_birth: F64,
    t_update: F64,
) -> tuple[F64, F64, F64, F64, F64, F64]:
    """(box, covariance, score, velocity, age_s, time_since_update_s) of the reported
    ``rows``: a track in the step (``in_step``) from the step's report (its row ``where``),
    the others (in ``rows`` order) from their predicted states ``x_away`` / ``p_away``: the
    box the state's first seven values with the yaw wrapped once (``motion.predicted_boxes``),
    the covariance its ``POS_VEL`` block. ``out_cov`` empty: the report has no covariance (a
    step row's is left unset, as the numpy gather left it); ``kalman``: any covariance at all
    (else the second array is empty)."""
    k = rows.shape[0]
    box = np.empty((k, _BOX))
    cov = np.empty((k if kalman else 0, 6, 6))
    out_score = np.empty(k)
    velocity = np.empty((k, 3))
    age_s = np.empty(k)
    tsu_s = np.empty(k)
    a = 0
    for j in range(k):
        r = rows[j]
        if in_step[r]:
            w = where[r]
            box[j, :] = out_params[w, :_BOX]
            if kalman and out_cov.shape[0] > 0:
                cov[j] = out_cov[w]
        else:
            for c in range(_BOX):
                box[j, c] = x_away[a, c]
            box[j, YAW] = wrap_once(box[j, YAW])
            if kalman:
                for u in range(6):
                    for v in range(6):
                        cov[j, u, v] = p_away[a, POS_VEL[u], POS_VEL[v]]
            a += 1
        out_score[j] = match_score[r] if fresh[r] or coast[r] else score[r]
        for c in range(3):
            velocity[j, c] = x[r, 7 + c]
        age_s[j] = t - t_birth[r]
        tsu_s[j] = t - t_update[r]
    return box, cov, out_score, velocity, age_s, tsu_s


_INT32_MAX = np.iinfo(np.int32).max


@kernel("int32[::1](int32[:, :], int64)")
def counter_in(misses: I32, s: int) -> I32:
    """The ``time_since_update`` a step of sensor ``s`` starts each track from, such that its
    own ``+ 1`` for a track ``s`` misses gives the track's counter after the miss: the least
    of ``s``'s misses (then one more) and every other in-view sensor's (-1: not in its view
    since)."""
    n, n_s = misses.shape
    out = np.empty(n, dtype=np.int32)
    for i in range(n):
        least = _INT32_MAX
        for j in range(n_s):
            if j != s and 0 <= misses[i, j] < least:
                least = misses[i, j]
        out[i] = min(max(misses[i, s], 0), least - 1)
    return out
