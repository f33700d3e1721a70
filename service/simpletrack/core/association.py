"""Assignment of detections to track predictions over a distance matrix."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import numpy.typing as npt
from scipy.optimize import linear_sum_assignment

from simpletrack.core.boxes import F64
from simpletrack.core.config import Matcher

I64 = npt.NDArray[np.int64]


@dataclass(frozen=True, slots=True)
class Assignment:
    """Matched (det, track) rows; unmatched detections in the reference's order (never
    assigned first, in index order, then those rejected by the threshold); unmatched tracks."""

    det: I64
    track: I64
    unmatched_dets: I64
    unmatched_tracks: I64


def _finish(rows: I64, cols: I64, dist: F64, max_distance: float) -> Assignment:
    n, m = dist.shape
    ok = dist[rows, cols] <= max_distance
    det_assigned = np.zeros(n, dtype=bool)
    det_assigned[rows] = True
    trk_matched = np.zeros(m, dtype=bool)
    trk_matched[cols[ok]] = True
    unmatched_dets = np.concatenate([np.flatnonzero(~det_assigned), rows[~ok]])
    return Assignment(
        det=rows[ok].astype(np.int64),
        track=cols[ok].astype(np.int64),
        unmatched_dets=unmatched_dets.astype(np.int64),
        unmatched_tracks=np.flatnonzero(~trk_matched).astype(np.int64),
    )


def hungarian(dist: F64, max_distance: float) -> Assignment:
    """Optimal assignment on the full matrix, then pairs over the threshold are rejected
    (the reference's order of operations: gating first could change the optimum)."""
    if dist.size == 0:
        rows = cols = np.zeros(0, dtype=np.int64)
    else:
        r, c = linear_sum_assignment(dist)
        rows, cols = r.astype(np.int64), c.astype(np.int64)
    return _finish(rows, cols, dist, max_distance)


def greedy(dist: F64, max_distance: float) -> Assignment:
    """Pairs by ascending distance, each taken when both sides are free. Only pairs within
    the threshold are sorted and walked: any later pair would be rejected anyway."""
    n, m = dist.shape
    cand_r, cand_c = np.nonzero(dist <= max_distance)
    order = np.argsort(dist[cand_r, cand_c], kind="stable")
    det_free = np.ones(n, dtype=bool)
    trk_free = np.ones(m, dtype=bool)
    rows: list[int] = []
    cols: list[int] = []
    limit = min(n, m)
    for r, c in zip(cand_r[order].tolist(), cand_c[order].tolist(), strict=True):
        if det_free[r] and trk_free[c]:
            det_free[r] = trk_free[c] = False
            rows.append(r)
            cols.append(c)
            if len(rows) == limit:
                break
    return _finish(
        np.array(rows, dtype=np.int64), np.array(cols, dtype=np.int64), dist, max_distance
    )


def assign(dist: F64, max_distance: float, matcher: Matcher) -> Assignment:
    if matcher is Matcher.HUNGARIAN:
        return hungarian(dist, max_distance)
    return greedy(dist, max_distance)
