"""Exact gates: the (a, b) box pairs that CAN pass a test, found on a BEV grid instead of over
all N x M pairs, so that a frame costs time and memory near-linear in its boxes.

``grid_pairs`` lists the same-group pairs whose centres lie in neighbouring cells of a grid of
side ``cell[group]`` and that a predicate keeps. It never misses a pair closer than the cell
side: |dx| <= s puts two centres in the same or adjacent columns (likewise rows), so searching
the 3 x 3 cells around each box suffices. Every gate below is a necessary condition, proven
in its docstring: a pair it drops provably fails the exact test, so computing the exact value
only on the kept pairs changes no result. ``_MARGIN`` (relative, far above rounding error)
keeps every proof valid for the float values the exact code computes.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
import numpy.typing as npt

from simpletrack.core.boxes import H, L, W, X, Y, Z
from simpletrack.core.config import Metric, VerticalOverlap

F64 = npt.NDArray[np.float64]
I64 = npt.NDArray[np.int64]
Bool = npt.NDArray[np.bool_]
Keep = Callable[[I64, I64], Bool]

__all__ = [
    "Keep",
    "association_pairs",
    "circumradius",
    "grid_pairs",
    "overlap_keep",
]

_MARGIN = 1e-6
# Candidate pairs expanded per vectorised batch: bounds temporaries (tens of MB).
_BATCH = 1 << 20
# At most this many cells per axis and group: keys stay exact in int64 whatever the spread.
_MAX_CELLS = 1 << 20
# The nine neighbour offsets of a cell (itself included).
_OFFSETS = [(dx, dy) for dx in (-1, 0, 1) for dy in (-1, 0, 1)]


def _empty() -> tuple[I64, I64]:
    return np.zeros(0, dtype=np.int64), np.zeros(0, dtype=np.int64)


def circumradius(p: F64) -> F64:
    """BEV circumscribed radius of each box, the same arithmetic as geometry's overlap gate."""
    return np.asarray(np.hypot(p[:, L], p[:, W]) / 2, dtype=np.float64)


def _inradius(p: F64) -> F64:
    return np.asarray(np.minimum(p[:, L], p[:, W]) / 2, dtype=np.float64)


def _cells(x: F64, y: F64, g: I64, side: F64, lo_x: F64, lo_y: F64) -> tuple[I64, I64]:
    s = side[g]
    # Infinite side (no gate possible): the whole group is one cell.
    finite = np.isfinite(s)
    with np.errstate(invalid="ignore"):
        cx = np.where(finite, np.floor((x - lo_x[g]) / s), 0.0)
        cy = np.where(finite, np.floor((y - lo_y[g]) / s), 0.0)
    return cx.astype(np.int64) + 1, cy.astype(np.int64) + 1


def grid_pairs(
    a_xy: F64,
    a_group: I64,
    b_xy: F64,
    b_group: I64,
    cell: F64,
    keep: Keep,
) -> tuple[I64, I64]:
    """Pairs (i, j), row-major, with ``a_group[i] == b_group[j]``, centres at most
    ``cell[group]`` apart along each axis (at least; farther pairs may be listed too) and
    ``keep(i, j)`` true. ``cell`` is indexed by group (>= 0); inf lists the group's every pair."""
    na, nb = a_xy.shape[0], b_xy.shape[0]
    if na == 0 or nb == 0:
        return _empty()
    groups = int(max(a_group.max(), b_group.max())) + 1
    side = np.asarray(cell, dtype=np.float64).copy()
    if side.size < groups:
        raise ValueError(f"{side.size} cell sides for {groups} groups")
    xs = np.concatenate([a_xy[:, 0], b_xy[:, 0]])
    ys = np.concatenate([a_xy[:, 1], b_xy[:, 1]])
    gs = np.concatenate([a_group, b_group])
    lo_x = np.full(groups, np.inf)
    lo_y = np.full(groups, np.inf)
    hi = np.full(groups, -np.inf)
    np.minimum.at(lo_x, gs, xs)
    np.minimum.at(lo_y, gs, ys)
    np.maximum.at(hi, gs, np.maximum(xs - lo_x[gs], ys - lo_y[gs]))
    # A coarser grid than asked is still exact (it lists more pairs): cap the cell count.
    side = np.maximum(side[:groups], hi / _MAX_CELLS)
    side[~(side > 0)] = np.inf
    ax, ay = _cells(a_xy[:, 0], a_xy[:, 1], a_group, side, lo_x, lo_y)
    bx, by = _cells(b_xy[:, 0], b_xy[:, 1], b_group, side, lo_x, lo_y)
    span = _MAX_CELLS + 3

    def key(g: I64, cx: I64, cy: I64) -> I64:
        return np.asarray((g * span + cx) * span + cy, dtype=np.int64)

    b_key = key(b_group, bx, by)
    order = np.argsort(b_key, kind="stable")
    sorted_key = b_key[order]
    # Per a-box and offset: the run [lo, hi) of sorted b-boxes in that neighbour cell.
    runs = []
    for ox, oy in _OFFSETS:
        k = key(a_group, ax + ox, ay + oy)
        first = np.searchsorted(sorted_key, k, side="left")
        runs.append((first, np.searchsorted(sorted_key, k, side="right") - first))
    per_row = np.sum([count for _, count in runs], axis=0)
    bounds = np.concatenate([[0], np.cumsum(per_row)])
    found_i: list[I64] = []
    found_j: list[I64] = []
    r0 = 0
    while r0 < na:
        # Rows r0..r1 expand to about _BATCH candidates (one row may exceed it alone).
        r1 = max(int(np.searchsorted(bounds, bounds[r0] + _BATCH, side="right")) - 1, r0 + 1)
        r1 = min(r1, na)
        rows = np.arange(r0, r1, dtype=np.int64)
        for first, count in runs:
            c = count[r0:r1]
            total = int(c.sum())
            if total == 0:
                continue
            i = np.repeat(rows, c)
            start = np.repeat(np.cumsum(c) - c, c)
            j = order[np.repeat(first[r0:r1], c) + (np.arange(total) - start)]
            ok = keep(i, j)
            found_i.append(i[ok])
            found_j.append(j[ok])
        r0 = r1
    if not found_i:
        return _empty()
    i = np.concatenate(found_i)
    j = np.concatenate(found_j)
    rank = np.argsort(i * nb + j, kind="stable")
    return i[rank], j[rank]


def _d2(pa: F64, pb: F64, i: I64, j: I64) -> F64:
    d2 = np.square(pa[i, X] - pb[j, X])
    d2 += np.square(pa[i, Y] - pb[j, Y])
    return np.asarray(d2, dtype=np.float64)


def overlap_keep(pa: F64, pb: F64, slack: float) -> tuple[Keep, float]:
    """Pairs whose circumscribed BEV circles meet, ``d^2 <= (ra + rb)^2 (1 + slack)``: a pair
    outside has disjoint footprints, so zero intersection. Returns the predicate and the grid
    side that finds every such pair (twice the largest radius, with margin)."""
    ra, rb = circumradius(pa), circumradius(pb)

    def keep(i: I64, j: I64) -> Bool:
        reach = ra[i] + rb[j]
        reach *= reach
        return np.asarray(_d2(pa, pb, i, j) <= reach * (1.0 + slack))

    widest = max(float(ra.max(initial=0.0)), float(rb.max(initial=0.0)))
    return keep, 2.0 * widest * np.sqrt(1.0 + slack) * (1.0 + _MARGIN)


def _giou_side(pa: F64, pb: F64, t: float, vertical: VerticalOverlap, three_d: bool) -> float:
    """Grid side for the GIoU gate: an upper bound of max(ra + rb, R_ab) over the pairs,
    R_ab the radius of ``_giou_keep``. With r the inradius and A = l w: (A_a + A_b)/(r_a + r_b)
    <= max(A/r) (mediant), and the vertical factor of the 3D bound is at most 1 (exact union
    >= max(h_a, h_b)) or 2 (reference union >= (h_a + h_b)/2), also <= A_max / r_min."""
    p = np.concatenate([pa, pb])
    area, r = p[:, L] * p[:, W], _inradius(p)
    bound = float(np.max(area / r))
    if three_d and vertical is VerticalOverlap.REFERENCE:
        bound = min(2.0 * bound, float(area.max() / r.min()))
    reach = 2.0 * float(circumradius(p).max())
    return max(reach, bound * (1.0 + 2 * _MARGIN) / (2.0 - t)) * (1.0 + _MARGIN)


def _giou_keep(
    pa: F64, pb: F64, t: float, vertical: VerticalOverlap, three_d: bool, slack: float
) -> Keep:
    """Pairs that may have ``1 - GIoU <= t`` (t < 2). Proof that a dropped pair cannot:
    it is outside the circle gate, so I = 0 (also in the exact code, whose own gate is tighter
    by ``slack``) and GIoU = U/C - 1 with U = A_a + A_b (BEV) or V_a + V_b (3D), C the enclosing
    measure (the exact mode's max(C, U) only lowers U/C). The BEV hull contains the trapezoid
    spanned by the diameters of both inscribed discs normal to the centre line, of area
    d (r_a + r_b) (d the centre distance, r = min(l, w)/2); the vertical union is at least
    |dz| + (h_a + h_b)/2 (both modes) and max(h_a, h_b) (exact mode). So
    U/C <= U / (d (r_a + r_b) z_lb), and a pair with U (1 + margin) < (2 - t) d (r_a + r_b) z_lb
    has GIoU < 1 - t, i.e. distance > t."""
    overlap, _ = overlap_keep(pa, pb, slack)
    ia, ib = _inradius(pa), _inradius(pb)
    size_a, size_b = pa[:, L] * pa[:, W], pb[:, L] * pb[:, W]
    if three_d:
        size_a, size_b = size_a * pa[:, H], size_b * pb[:, H]
    exact = vertical is VerticalOverlap.EXACT

    def keep(i: I64, j: I64) -> Bool:
        near = overlap(i, j)
        enclose = np.sqrt(_d2(pa, pb, i, j)) * (ia[i] + ib[j]) * (2.0 - t)
        if three_d:
            ha, hb = pa[i, H], pb[j, H]
            z_lb = np.abs(pa[i, Z] - pb[j, Z]) + (ha + hb) / 2
            if exact:
                np.maximum(z_lb, np.maximum(ha, hb), out=z_lb)
            enclose *= z_lb
        return np.asarray(near | ((size_a[i] + size_b[j]) * (1.0 + _MARGIN) >= enclose))

    return keep


def association_pairs(
    metric: Metric,
    dets: F64,
    det_group: I64,
    preds: F64,
    pred_group: I64,
    threshold: F64,
    *,
    vertical: VerticalOverlap = VerticalOverlap.EXACT,
    innovation: F64 | None = None,
) -> tuple[I64, I64]:
    """Same-group (det, pred) pairs, row-major, that may have distance <= ``threshold[group]``
    under ``metric``; every pair left out provably has a larger distance (see each gate).

    - IoU 3D/BEV (t < 1): disjoint circumscribed circles mean I = 0, distance exactly 1 > t.
    - GIoU 3D/BEV (t < 2): ``_giou_keep``.
    - L2: the 3D centre distance is at least the BEV one.
    - Mahalanobis: d^T S^-1 d >= |d|^2 / lambda_max(S) >= d_bev^2 / lambda_max(S), so a pair
      with d_bev > t sqrt(lambda_max(S_j)) is out (yaw folding leaves x, y alone).
    A threshold the metric's range cannot exceed (IoU t >= 1, GIoU t >= 2) gates nothing.
    """
    metric = Metric(metric)
    thr = np.asarray(threshold, dtype=np.float64)
    groups = int(max(det_group.max(initial=0), pred_group.max(initial=0))) + 1
    if dets.shape[0] == 0 or preds.shape[0] == 0:
        return _empty()
    cell = np.full(groups, np.inf)
    keeps: dict[int, Keep] = {}
    present = np.intersect1d(det_group, pred_group).tolist()
    if metric is Metric.MAHALANOBIS and innovation is None:
        raise ValueError("the mahalanobis metric needs the tracks' innovation covariances")
    for g in present:
        t = float(thr[g])
        da, pb = np.flatnonzero(det_group == g), np.flatnonzero(pred_group == g)
        a, b = dets[da], preds[pb]
        if metric in (Metric.IOU_3D, Metric.IOU_BEV) and t < 1.0:
            keeps[g], cell[g] = (
                overlap_keep(dets, preds, _MARGIN)[0],
                overlap_keep(a, b, _MARGIN)[1],
            )
        elif metric in (Metric.GIOU_3D, Metric.GIOU_BEV) and t < 2.0:
            three_d = metric is Metric.GIOU_3D
            keeps[g] = _giou_keep(dets, preds, t, vertical, three_d, _MARGIN)
            cell[g] = _giou_side(a, b, t, vertical, three_d)
        elif metric is Metric.L2:
            limit = t * t * (1.0 + _MARGIN)
            keeps[g] = _l2_keep(dets, preds, limit)
            cell[g] = t * (1.0 + _MARGIN) ** 2
        elif metric is Metric.MAHALANOBIS and innovation is not None:
            scale = np.sqrt(np.linalg.eigvalsh(innovation)[:, -1])
            keeps[g] = _scaled_keep(dets, preds, t * scale * (1.0 + _MARGIN))
            cell[g] = t * float(scale[pb].max()) * (1.0 + _MARGIN) ** 2

    def keep(i: I64, j: I64) -> Bool:
        out = np.zeros(i.size, dtype=bool)
        g = det_group[i]
        for code, test in keeps.items():
            sel = np.flatnonzero(g == code)
            out[sel] = test(i[sel], j[sel])
        ungated = ~np.isin(g, list(keeps))
        out[ungated] = True
        return out

    return grid_pairs(dets[:, X : Y + 1], det_group, preds[:, X : Y + 1], pred_group, cell, keep)


def _l2_keep(pa: F64, pb: F64, limit2: float) -> Keep:
    def keep(i: I64, j: I64) -> Bool:
        return np.asarray(_d2(pa, pb, i, j) <= limit2)

    return keep


def _scaled_keep(pa: F64, pb: F64, reach_b: F64) -> Keep:
    def keep(i: I64, j: I64) -> Bool:
        return np.asarray(_d2(pa, pb, i, j) <= np.square(reach_b[j]))

    return keep
