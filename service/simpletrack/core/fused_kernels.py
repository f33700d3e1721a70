"""A fused vehicle's per-frame bookkeeping, compiled (core/vehicle.py ``_columns``, ``_report``).

Both were numpy over the vehicle's ~100-200 tracks: some forty calls each, every one costing
more than its arithmetic, a third of a fused frame's time in the service (docs/BENCHMARKS.md,
"Fused vehicles"). Here each is one loop over the tracks with the same operations in the same
order (additions, comparisons, copies), so the results are the numpy code's bit for bit; the
logarithms and exponentials stay in numpy, outside (``evidence`` comes in computed).
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt

from simpletrack.core.advance_kernels import policy_shows
from simpletrack.core.jit import kernel

F64 = npt.NDArray[np.float64]
I8 = npt.NDArray[np.int8]
I32 = npt.NDArray[np.int32]
I64 = npt.NDArray[np.int64]
B = npt.NDArray[np.bool_]

__all__ = ["fused_columns", "report_rows"]

_COASTED, _MATCHED = 0, 1  # lifecycle.UpdateKind
_TENTATIVE, _CONFIRMED = 0, 1  # lifecycle.TrackState

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
