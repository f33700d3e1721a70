"""Assignment of detections to track predictions over a distance matrix."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from simpletrack.core.boxes import F64
from simpletrack.core.config import Matcher
from simpletrack.core.solvers import linear_sum_assignment, min_weight_full_bipartite_matching

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
    rows, cols = _greedy_walk(cand_r, cand_c, dist[cand_r, cand_c], n, m)
    return _finish(rows, cols, dist, max_distance)


def _greedy_walk(cand_r: I64, cand_c: I64, d: F64, n: int, m: int) -> tuple[I64, I64]:
    """The greedy walk over candidate pairs listed row-major (ties keep that order)."""
    order = np.argsort(d, kind="stable")
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
    return np.array(rows, dtype=np.int64), np.array(cols, dtype=np.int64)


def assign(dist: F64, max_distance: float, matcher: Matcher) -> Assignment:
    if matcher is Matcher.HUNGARIAN:
        return hungarian(dist, max_distance)
    return greedy(dist, max_distance)


def _sparse_finish(rows: I64, cols: I64, n: int, m: int, keep_order: bool = False) -> Assignment:
    """Every listed pair is within the threshold: none is rejected, so the unmatched
    detections are the never assigned ones, in index order (as ``_finish`` lists them)."""
    if not keep_order:
        order = np.argsort(rows, kind="stable")
        rows, cols = rows[order], cols[order]
    rows, cols = rows.astype(np.int64), cols.astype(np.int64)
    det_matched = np.zeros(n, dtype=bool)
    det_matched[rows] = True
    trk_matched = np.zeros(m, dtype=bool)
    trk_matched[cols] = True
    return Assignment(
        det=rows,
        track=cols,
        unmatched_dets=np.flatnonzero(~det_matched).astype(np.int64),
        unmatched_tracks=np.flatnonzero(~trk_matched).astype(np.int64),
    )


def sparse_hungarian(
    rows: I64, cols: I64, dist: F64, n: int, m: int, far_cost: float
) -> Assignment:
    """The optimal assignment of an (n, m) problem given only its feasible pairs (distance
    within the threshold), every other pair costing ``far_cost``.

    With a constant cost K off the listed pairs, a full assignment of cost k K - sum over its
    listed pairs of (K - d) (k = min(n, m)) exists for every matching M of listed pairs (the
    rest is filled with K pairs), so the optimum is the matching maximising sum (K - d): a
    linear problem on the listed pairs only. Solved as a min-cost perfect matching (scipy's
    sparse LAPJV) of the graph: det i - track j (d + 1), det i - its spare column (K/2 + 1),
    track j's spare row - track j (K/2 + 1), track j's spare row - det i's spare column (1)
    for every listed (i, j); a perfect matching always exists (M's pairs swap to spare-spare
    edges), every one has n + m edges, so the +1 (keeping weights positive: scipy drops
    explicit zeros) moves no optimum, and its cost is constant + sum over M of (d - K).
    Unmatched detections come in index order (for n <= m the dense solve's order too)."""
    keep = dist <= far_cost  # pairs dearer than K are never worth taking
    r, c, d = rows[keep].astype(np.int64), cols[keep].astype(np.int64), dist[keep]
    if r.size == 0:
        return _sparse_finish(r, c, n, m)
    half = far_cost / 2 + 1.0
    size = n + m
    ar, ac = np.arange(n, dtype=np.int64), np.arange(m, dtype=np.int64)
    from scipy.sparse import coo_matrix  # with the solver: not imported unless it runs

    graph = coo_matrix(
        (
            np.concatenate([d + 1.0, np.full(n, half), np.full(m, half), np.ones(r.size)]),
            (np.concatenate([r, ar, n + ac, n + c]), np.concatenate([c, m + ar, ac, m + r])),
        ),
        shape=(size, size),
    ).tocsr()
    row_of, col_of = min_weight_full_bipartite_matching(graph)
    real = (row_of < n) & (col_of < m)
    return _sparse_finish(row_of[real], col_of[real], n, m)


def assign_pairs(
    rows: I64,
    cols: I64,
    dist: F64,
    shape: tuple[int, int],
    max_distance: float,
    matcher: Matcher,
    far_cost: float,
) -> Assignment:
    """``assign`` from the listed pairs of an (n, m) problem, row-major, that include every
    pair within ``max_distance``. Greedy is exactly ``assign`` on the full matrix (only pairs
    within the threshold are ever walked); Hungarian is ``sparse_hungarian``."""
    n, m = shape
    ok = dist <= max_distance
    rows, cols, dist = rows[ok], cols[ok], dist[ok]
    if matcher is Matcher.HUNGARIAN:
        return sparse_hungarian(rows, cols, dist, n, m, far_cost)
    r, c = _greedy_walk(rows.astype(np.int64), cols.astype(np.int64), dist, n, m)
    return _sparse_finish(r, c, n, m, keep_order=True)
