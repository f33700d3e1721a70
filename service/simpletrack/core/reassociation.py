"""Re-association across a bridged gap: the detections and tracks the ordinary stages left
apart on the first frame after an outage, matched by where the tracks went.

Why not the stage-1 gate. After a gap of seconds the prediction misses by metres (KITTI train,
``python -m simpletrack.bench.gaps``: median 1.1 m after 1 s, 9 m after 5 s, 20 m after 10 s),
far beyond any box-overlap gate, and a Kalman covariance propagated over the gap is as wide
as the error is (about 1-2 m/s of velocity doubt per second), so it would take the neighbour
as readily as the object: parked cars stand 5-8 m apart. Most of the error is shared, though:
in a sensor frame that moves (KITTI's camera) every track's velocity holds the ego motion, and
what the ego did over the gap (braked, turned) shifts all predictions alike. So the shift is
estimated from the scene first: every nearby (detection, track) pair proposes its offset, the
offset most tracks agree with (to within ``TOLERANCE_M``) wins, and only pairs that agree with
it are matched, Hungarian on their residual. A lone track cannot tell its own motion from the
ego's, so it gets no shift and only the tolerance around its prediction. A wrong id costs more
than a new one, hence the tight tolerance rather than a wide radius.
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt

from simpletrack.core.boxes import F64
from simpletrack.core.solvers import linear_sum_assignment

I64 = npt.NDArray[np.int64]
I32 = npt.NDArray[np.int32]

# How far a prediction may be off before the shift (m, and m per second of gap): 2 m/s
# covers the measured median errors above with room (the 90th percentile, 5 s: 19 m).
REACH_M = 2.0
REACH_M_PER_S = 4.0
# How close a detection must come to its shifted prediction: under half a car's spacing.
TOLERANCE_M = 2.0
# A pair is taken only when nothing else of its class is this close to either of its ends.
AMBIGUOUS_M = 6.0
# Beyond this the scene cannot place a track: after 10 s even the best rigid fit of the true
# positions leaves 6 m (median), the spacing of parked cars; a match there is a guess.
MAX_DT_S = 7.0
# Two tracks at least must agree on a shift before it is believed.
MIN_SUPPORT = 2
# At most this many proposals are weighed (the nearest pairs): bounds the (P, P) agreement.
MAX_PROPOSALS = 400

_EMPTY = np.zeros(0, dtype=np.int64)


def _support(offsets: F64, det: I64, trk: I64, n_det: int, n_trk: int) -> I64:
    """For each proposed offset, how many distinct tracks (and detections: the fewer of the
    two) some pair explains to within the tolerance."""
    agree = np.hypot(*(offsets[:, None, :] - offsets[None, :, :]).transpose(2, 0, 1))
    agree = agree <= TOLERANCE_M
    tracks = np.zeros((offsets.shape[0], n_trk), dtype=bool)
    dets = np.zeros((offsets.shape[0], n_det), dtype=bool)
    h, p = np.nonzero(agree)
    tracks[h, trk[p]] = True
    dets[h, det[p]] = True
    return np.asarray(np.minimum(tracks.sum(axis=1), dets.sum(axis=1)), dtype=np.int64)


def common_shift(d_xy: F64, t_xy: F64, same_class: npt.NDArray[np.bool_], reach: F64) -> F64:
    """The horizontal offset (2,) most tracks' predictions agree they are off by; zero when
    fewer than ``MIN_SUPPORT`` agree."""
    off = d_xy[:, None, :] - t_xy[None, :, :]
    dist = np.hypot(off[..., 0], off[..., 1])
    det, trk = np.nonzero(same_class & (dist <= reach[None, :]))
    if det.size == 0:
        return np.zeros(2)
    if det.size > MAX_PROPOSALS:
        near = np.argsort(dist[det, trk], kind="stable")[:MAX_PROPOSALS]
        det, trk = det[near], trk[near]
    offsets = off[det, trk]
    support = _support(offsets, det, trk, d_xy.shape[0], t_xy.shape[0])
    top = support.max()
    if top < MIN_SUPPORT:
        return np.zeros(2)
    best = np.flatnonzero(support == top)
    pick = best[np.argmin(np.hypot(offsets[best, 0], offsets[best, 1]))]
    inliers = np.hypot(*(offsets - offsets[pick]).T) <= TOLERANCE_M
    # Two distinct shifts as well supported (a row of parked cars seen one car along): the
    # scene cannot say which, and a guess would hand the row its neighbours' ids.
    rival = np.hypot(*(offsets[best] - offsets[pick]).T) > 2 * TOLERANCE_M
    if rival.any():
        return np.zeros(2)
    return np.asarray(offsets[inliers].mean(axis=0), dtype=np.float64)


def reassociate(d_xy: F64, d_cls: I32, t_xy: F64, t_cls: I32, t_dt: F64) -> tuple[I64, I64]:
    """(detection, track) index pairs matched across a gap: same class, the detection within
    ``TOLERANCE_M`` of the track's prediction moved by the scene's common shift, and within
    reach of the unshifted prediction (``REACH_M + REACH_M_PER_S`` x the track's dt)."""
    if d_xy.shape[0] == 0 or t_xy.shape[0] == 0:
        return _EMPTY, _EMPTY
    same = d_cls[:, None] == t_cls[None, :]
    reach = REACH_M + REACH_M_PER_S * t_dt
    shift = common_shift(d_xy, t_xy, same, reach)
    raw = np.hypot(*(d_xy[:, None, :] - t_xy[None, :, :]).transpose(2, 0, 1))
    resid = np.hypot(*(d_xy[:, None, :] - t_xy[None, :, :] - shift).transpose(2, 0, 1))
    ok = same & (raw <= reach[None, :]) & (resid <= TOLERANCE_M) & (t_dt <= MAX_DT_S)[None, :]
    # Only unambiguous pairs: nothing else of the class within ``AMBIGUOUS_M`` of either end
    # of the pair (the detection's other tracks, the track's other detections).
    near = same & (raw <= reach[None, :]) & (resid <= AMBIGUOUS_M)
    ok &= (near.sum(axis=0, keepdims=True) == 1) & (near.sum(axis=1, keepdims=True) == 1)
    if not ok.any():
        return _EMPTY, _EMPTY
    # Infeasible pairs cost more than any feasible set of them, so the optimum never trades
    # a feasible pair for one; they are dropped after.
    cost = np.where(ok, resid, TOLERANCE_M * (1 + min(ok.shape)))
    r, c = linear_sum_assignment(cost)
    keep = ok[r, c]
    return r[keep].astype(np.int64), c[keep].astype(np.int64)
