"""Vectorised box geometry: BEV intersection and hull areas, IoU/GIoU, centre and Mahalanobis distances.

Every pairwise function takes ``a`` (N, 7) and ``b`` (M, 7) box parameters (x, y, z, yaw, l, w, h)
and returns a float64 (N, M) matrix. Each pair is solved in box a's own frame (a centred at the
origin and axis-aligned): coordinates stay small even kilometres from the world origin, and a's
four half-planes become the two slabs |x| <= l/2 and |y| <= w/2.

Both areas are exact up to rounding (no tolerances, no sorting, fixed-size arrays):
- Intersection: b's outline clipped by a's two slabs. Each edge keeps three slots (its start, and
  the ends of its part inside the slab), clamped into the slab: an outside run then becomes
  a detour along the slab's boundary line, which encloses no area, so the shoelace formula over
  the fixed slots gives the clipped area. Only pairs whose circumscribed circles meet are clipped.
- Hull: the hull's support function is the max of both boxes' support functions h_a, h_b. Listing
  the hull's vertices as the winners at every edge normal n of either box and summing the shoelace
  terms collapses to a closed form:
      area(hull) = area(b) + sum over the 8 edges e of both boxes of |e|/2 * max(0, h_a(n_e) - h_b(n_e)).
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt

from simpletrack.core.boxes import YAW, H, L, W, X, Y, Z
from simpletrack.core.config import Metric, VerticalOverlap
from simpletrack.core.gate import circumradius, grid_pairs, overlap_keep

F64 = npt.NDArray[np.float64]
I64 = npt.NDArray[np.int64]

__all__ = [
    "bev_corners",
    "bev_hull_area",
    "bev_intersection_area",
    "distance_matrix",
    "distance_pairs",
    "fold_yaw",
    "giou_3d",
    "giou_bev",
    "iou_3d",
    "iou_3d_pairs",
    "iou_bev",
    "l2_distance",
    "mahalanobis",
]

# Pairs per vectorised batch: bounds temporaries (tens of MB) whatever N x M is, while keeping
# the per-batch Python overhead negligible.
_CHUNK = 1 << 15
# The reference code's iou3d divides by (U + 1e-5); reproduced in REFERENCE mode only.
_REFERENCE_EPS = 1e-5
# Circle gate margin: pairs just outside it would clip to zero area anyway.
_GATE_SLACK = 1e-9

# Corner signs, counter-clockwise from front-left (+l/2, +w/2).
_SX = np.array([1.0, -1.0, -1.0, 1.0])
_SY = np.array([1.0, 1.0, -1.0, -1.0])


def _params(p: npt.ArrayLike, name: str) -> F64:
    arr = np.asarray(p, dtype=np.float64)
    if arr.ndim != 2 or arr.shape[1] != 7:
        raise ValueError(f"{name} must be (N, 7) box parameters, got shape {arr.shape}")
    return arr


def bev_corners(params: npt.ArrayLike) -> F64:
    """(N, 4, 2) BEV corners, counter-clockwise, starting at front-left (+l/2, +w/2)."""
    p = _params(params, "params")
    c, s = np.cos(p[:, YAW])[:, None], np.sin(p[:, YAW])[:, None]
    lx = _SX * (p[:, L, None] / 2)
    ly = _SY * (p[:, W, None] / 2)
    x = p[:, X, None] + c * lx - s * ly
    y = p[:, Y, None] + s * lx + c * ly
    return np.stack([x, y], axis=2)


def _relative(a: F64, b: F64, *, exact_yaw: bool) -> tuple[F64, F64, F64, F64]:
    """b's centre (dx, dy) and heading (cos, sin) in a's frame, for row-aligned or broadcast
    (..., 7) parameter arrays.

    ``exact_yaw`` takes cos/sin of the yaw difference (exactly 1, 0 for equal yaws); otherwise
    product formulas of per-box cos/sin, which avoid trig over all N x M pairs.
    """
    ca, sa = np.cos(a[..., YAW]), np.sin(a[..., YAW])
    dxw = b[..., X] - a[..., X]
    dyw = b[..., Y] - a[..., Y]
    if exact_yaw:
        dyaw = b[..., YAW] - a[..., YAW]
        c, s = np.cos(dyaw), np.sin(dyaw)
    else:
        cb, sb = np.cos(b[..., YAW]), np.sin(b[..., YAW])
        c, s = cb * ca + sb * sa, sb * ca - cb * sa
    return ca * dxw + sa * dyw, ca * dyw - sa * dxw, c, s


def _clip_slab(pts: F64, h: F64) -> F64:
    """Clip closed outlines ``pts`` (2, n, P) (coordinates u, v) to the slab |u| <= h (P,).

    Returns (2, 3n, P): per edge its start, then the ends of its part inside the slab (Liang-Barsky
    parameters clamped to [0, 1]), all with u clamped into the slab. Points of an outside run land
    on the slab's boundary line, where any back-and-forth encloses no area.
    """
    n, p = pts.shape[1], pts.shape[2]
    out = np.empty((2, n, 3, p))
    out[:, :, 0] = pts
    d = pts[:, _NEXT_OF[n]] - pts
    u, du = pts[0], d[0]
    with np.errstate(divide="ignore", invalid="ignore"):
        inv = 1.0 / du
        t_lo = (-h - u) * inv
        t_hi = (h - u) * inv
    t = np.empty((n, 2, p))
    # fmin / fmax skip the NaN of 0 * inf (an edge lying along a boundary line).
    np.fmin(t_lo, t_hi, out=t[:, 0])
    np.fmax(t_lo, t_hi, out=t[:, 1])
    np.fmin(t, 1.0, out=t)
    np.fmax(t, 0.0, out=t)
    ends = out[:, :, 1:]
    np.multiply(t, d[:, :, None], out=ends)
    ends += pts[:, :, None]
    flat = out.reshape(2, 3 * n, p)
    np.maximum(flat[0], -h, out=flat[0])
    np.minimum(flat[0], h, out=flat[0])
    return flat


# Cyclic successor index for outlines of 4, 12 and 36 points.
_NEXT_OF = {n: np.roll(np.arange(n), -1) for n in (4, 12, 36)}


def _shoelace(x: F64, y: F64) -> F64:
    """Signed areas of closed outlines (n, P), positive when counter-clockwise."""
    twice = np.sum(x[:-1] * y[1:] - x[1:] * y[:-1], axis=0)
    twice += x[-1] * y[0] - x[0] * y[-1]
    return np.asarray(0.5 * twice, dtype=np.float64)


def _intersection(a: F64, b: F64) -> F64:
    """BEV intersection areas of row-aligned boxes a, b (P, 7)."""
    dx, dy, c, s = _relative(a, b, exact_yaw=True)
    hl, hw = b[:, L] / 2, b[:, W] / 2
    ex, ey, fx, fy = c * hl, s * hl, -s * hw, c * hw
    sx, sy = _SX[:, None], _SY[:, None]
    pts = np.stack([dx + sx * ex + sy * fx, dy + sx * ey + sy * fy])  # b's corners (2, 4, P)
    pts = _clip_slab(pts, a[:, L] / 2)
    pts = _clip_slab(pts[::-1], a[:, W] / 2)[::-1]
    return _shoelace(pts[0], pts[1])


def _hull(a: F64, b: F64) -> F64:
    """BEV convex hull areas of broadcastable box arrays a, b (..., 7); see the module doc."""
    dx, dy, c, s = _relative(a, b, exact_yaw=False)
    ha, wa, hl, hw = a[..., L] / 2, a[..., W] / 2, b[..., L] / 2, b[..., W] / 2
    du, dv = np.abs(dx * c + dy * s), np.abs(dy * c - dx * s)  # b's centre along b's axes
    c, s, dx, dy = np.abs(c), np.abs(s), np.abs(dx), np.abs(dy)
    # Margins h_a - h_b along each edge normal, both boxes about their own centres: along a's
    # x and y, then along b's axis u and across it v. The centre offset d (>= 0) adds -d on one
    # side and +d on the other, and max(0, m - d) + max(0, m + d) = max(0, m + max(m, d)).
    mx = ha - (c * hl + s * hw)
    my = wa - (s * hl + c * hw)
    mu = ha * c + wa * s - hl
    mv = ha * s + wa * c - hw
    # Edge lengths: a's x normals 2 wa, y normals 2 ha; b's u normals 2 hw, v normals 2 hl.
    area = wa * np.maximum(mx + np.maximum(mx, dx), 0.0)
    area += ha * np.maximum(my + np.maximum(my, dy), 0.0)
    area += hw * np.maximum(mu + np.maximum(mu, du), 0.0)
    area += hl * np.maximum(mv + np.maximum(mv, dv), 0.0)
    area += 4.0 * hl * hw
    return np.asarray(area, dtype=np.float64)


def _hull_matrix(a: F64, b: F64) -> F64:
    """(N, M) hull areas, broadcasting over row blocks of a to bound temporaries."""
    n, m = a.shape[0], b.shape[0]
    out = np.empty((n, m))
    rows = max(1, _CHUNK // max(m, 1))
    for r0 in range(0, n, rows):
        out[r0 : r0 + rows] = _hull(a[r0 : r0 + rows, None, :], b[None, :, :])
    return out


def _areas(p: F64) -> F64:
    return np.asarray(p[:, L] * p[:, W], dtype=np.float64)


def _gate_all_pairs(pa: F64, pb: F64, ga: I64 | None, gb: I64 | None) -> tuple[I64, I64]:
    """``_gate`` by testing every pair at once (the same predicate, the same pairs)."""
    ra, rb = circumradius(pa), circumradius(pb)
    d2 = np.square(pa[:, None, X] - pb[None, :, X])
    d2 += np.square(pa[:, None, Y] - pb[None, :, Y])
    reach = ra[:, None] + rb[None, :]
    reach *= reach
    near = d2 <= reach * (1.0 + _GATE_SLACK)
    if ga is not None and gb is not None:
        near &= ga[:, None] == gb[None, :]
    i, j = np.nonzero(near)
    return i.astype(np.int64), j.astype(np.int64)


def _gate(pa: F64, pb: F64, ga: I64 | None, gb: I64 | None) -> tuple[I64, I64]:
    """Pairs (row-major) whose circumscribed circles meet, the only ones that can intersect;
    with group labels, only pairs within a group. Found on a BEV grid (core/gate.py): near-
    linear in the boxes, the same pairs as the all-pairs test."""
    if pa.shape[0] * pb.shape[0] <= _CHUNK:
        return _gate_all_pairs(pa, pb, ga, gb)  # small frames: one block is cheaper
    if ga is None or gb is None:
        ga, gb = np.zeros(pa.shape[0], np.int64), np.zeros(pb.shape[0], np.int64)
    else:
        _, codes = np.unique(np.concatenate([ga, gb]), return_inverse=True)
        ga, gb = codes[: pa.shape[0]].astype(np.int64), codes[pa.shape[0] :].astype(np.int64)
    keep, _ = overlap_keep(pa, pb, _GATE_SLACK)
    groups = int(max(ga.max(initial=0), gb.max(initial=0))) + 1
    widest = np.zeros(groups)
    np.maximum.at(widest, ga, circumradius(pa))
    np.maximum.at(widest, gb, circumradius(pb))
    cell = 2.0 * widest * np.sqrt(1.0 + _GATE_SLACK) * (1.0 + 1e-6)
    return grid_pairs(pa[:, X : Y + 1], ga, pb[:, X : Y + 1], gb, cell, keep)


def _gated_intersection(
    pa: F64, pb: F64, ga: I64 | None = None, gb: I64 | None = None
) -> tuple[I64, I64, F64]:
    """The gated pairs (see _gate) and their BEV intersection areas."""
    ia, ib = _gate(pa, pb, ga, gb)
    area = np.empty(ia.size)
    for start in range(0, ia.size, _CHUNK):
        i, j = ia[start : start + _CHUNK], ib[start : start + _CHUNK]
        area[start : start + i.size] = _intersection(pa[i], pb[j])
    return ia, ib, np.clip(area, 0.0, np.minimum(_areas(pa)[ia], _areas(pb)[ib]))


def bev_intersection_area(a: npt.ArrayLike, b: npt.ArrayLike) -> F64:
    """(N, M) areas of the BEV footprints' intersections."""
    pa, pb = _params(a, "a"), _params(b, "b")
    out = np.zeros((pa.shape[0], pb.shape[0]))
    ia, ib, area = _gated_intersection(pa, pb)
    out[ia, ib] = area
    return out


def bev_hull_area(a: npt.ArrayLike, b: npt.ArrayLike) -> F64:
    """(N, M) areas of the convex hulls of each pair's 8 BEV corners."""
    pa, pb = _params(a, "a"), _params(b, "b")
    hull = _hull_matrix(pa, pb)
    return np.maximum(hull, np.maximum(_areas(pa)[:, None], _areas(pb)[None, :]))


def _vertical(
    a: F64, b: F64, mode: VerticalOverlap, ia: I64 | None = None, ib: I64 | None = None
) -> tuple[F64, F64]:
    """Vertical overlap and union lengths: (N, M), or (P,) for the pairs (ia, ib)."""
    top_a, bot_a = a[:, Z] + a[:, H] / 2, a[:, Z] - a[:, H] / 2
    top_b, bot_b = b[:, Z] + b[:, H] / 2, b[:, Z] - b[:, H] / 2
    if ia is None or ib is None:
        top_a, bot_a, top_b, bot_b = top_a[:, None], bot_a[:, None], top_b[None], bot_b[None]
    else:
        top_a, bot_a, top_b, bot_b = top_a[ia], bot_a[ia], top_b[ib], bot_b[ib]
    if mode is VerticalOverlap.EXACT:
        overlap = np.maximum(0.0, np.minimum(top_a, top_b) - np.maximum(bot_a, bot_b))
        union = np.maximum(top_a, top_b) - np.minimum(bot_a, bot_b)
    else:
        # The reference's formula: wrong when one vertical extent contains the other.
        ab, ba = top_a - bot_b, top_b - bot_a
        overlap = np.maximum(0.0, np.minimum(ab, ba))
        union = np.maximum(ab, ba)
    return overlap, union


def _sparse_iou(
    pa: F64,
    pb: F64,
    ia: I64,
    ib: I64,
    inter: F64,
    *,
    three_d: bool,
    vertical: VerticalOverlap,
    reference_eps: bool,
) -> tuple[F64, F64, F64, F64]:
    """IoU on the gated pairs: (iou, union) per pair, and the per-box sizes (areas or volumes).

    ``reference_eps`` divides by (U + 1e-5) as the reference's iou3d does."""
    size_a, size_b = _areas(pa), _areas(pb)
    if three_d:
        inter = inter * _vertical(pa, pb, vertical, ia, ib)[0]
        size_a, size_b = size_a * pa[:, H], size_b * pb[:, H]
    union = size_a[ia] + size_b[ib] - inter
    if reference_eps:
        iou = inter / (union + _REFERENCE_EPS)
    else:
        iou = np.divide(inter, union, out=np.zeros_like(inter), where=union > 0)
    return iou, union, size_a, size_b


def _overlap(
    a: npt.ArrayLike,
    b: npt.ArrayLike,
    *,
    three_d: bool,
    generalized: bool,
    vertical: VerticalOverlap,
) -> F64:
    pa, pb = _params(a, "a"), _params(b, "b")
    n, m = pa.shape[0], pb.shape[0]
    # Intersections (and so IoU) are non-zero only on the gated pairs: work there sparsely.
    ia, ib, inter = _gated_intersection(pa, pb)
    reference_3d = three_d and vertical is VerticalOverlap.REFERENCE
    iou_g, union_g, size_a, size_b = _sparse_iou(
        pa,
        pb,
        ia,
        ib,
        inter,
        three_d=three_d,
        vertical=vertical,
        reference_eps=reference_3d and not generalized,
    )
    if not generalized:
        out = np.zeros((n, m))
        out[ia, ib] = iou_g
        return out
    # GIoU = I/U - (C - U)/C = I/U + U/C - 1 on every pair.
    enclosing = _hull_matrix(pa, pb)
    if three_d:
        enclosing *= _vertical(pa, pb, vertical)[1]
    union = size_a[:, None] + size_b[None, :]
    union[ia, ib] = union_g
    if not reference_3d:
        # The hull contains the union; rounding must not push GIoU above IoU.
        np.maximum(enclosing, union, out=enclosing)
    giou = np.divide(union, enclosing, out=np.ones_like(union), where=enclosing > 0)
    giou -= 1.0
    giou[ia, ib] += iou_g
    return giou


def iou_3d_pairs(
    a: npt.ArrayLike,
    b: npt.ArrayLike,
    *,
    vertical: VerticalOverlap = VerticalOverlap.EXACT,
    groups_a: npt.ArrayLike | None = None,
    groups_b: npt.ArrayLike | None = None,
) -> tuple[I64, I64, F64]:
    """Sparse 3D IoU: (rows, cols, iou) for every pair that can overlap (BEV circumscribed
    circles meet) and, given group labels (e.g. class codes), shares a group; every other pair
    has IoU 0. Rows are ascending (row-major). Same values as ``iou_3d``."""
    pa, pb = _params(a, "a"), _params(b, "b")
    ga = None if groups_a is None else np.asarray(groups_a).reshape(-1)
    gb = None if groups_b is None else np.asarray(groups_b).reshape(-1)
    if (ga is None) != (gb is None):
        raise ValueError("give group labels for both sides or for neither")
    if ga is not None and gb is not None and (ga.size != pa.shape[0] or gb.size != pb.shape[0]):
        raise ValueError(
            f"group labels {ga.size}, {gb.size} != box counts {pa.shape[0]}, {pb.shape[0]}"
        )
    ia, ib, inter = _gated_intersection(pa, pb, ga, gb)
    iou = _sparse_iou(
        pa,
        pb,
        ia,
        ib,
        inter,
        three_d=True,
        vertical=vertical,
        reference_eps=vertical is VerticalOverlap.REFERENCE,
    )[0]
    return ia, ib, iou


def iou_bev(
    a: npt.ArrayLike, b: npt.ArrayLike, *, vertical: VerticalOverlap = VerticalOverlap.EXACT
) -> F64:
    """BEV IoU (``vertical`` is accepted for a uniform signature; BEV has no vertical part)."""
    return _overlap(a, b, three_d=False, generalized=False, vertical=vertical)


def giou_bev(
    a: npt.ArrayLike, b: npt.ArrayLike, *, vertical: VerticalOverlap = VerticalOverlap.EXACT
) -> F64:
    """BEV GIoU: IoU - (hull - union) / hull, in (-1, 1]."""
    return _overlap(a, b, three_d=False, generalized=True, vertical=vertical)


def iou_3d(
    a: npt.ArrayLike, b: npt.ArrayLike, *, vertical: VerticalOverlap = VerticalOverlap.EXACT
) -> F64:
    """3D IoU; REFERENCE mode also reproduces the reference's ``I / (U + 1e-5)``."""
    return _overlap(a, b, three_d=True, generalized=False, vertical=vertical)


def giou_3d(
    a: npt.ArrayLike, b: npt.ArrayLike, *, vertical: VerticalOverlap = VerticalOverlap.EXACT
) -> F64:
    """3D GIoU (eq. 1 of the paper): I/U - (C - U)/C, C = hull area x vertical union."""
    return _overlap(a, b, three_d=True, generalized=True, vertical=vertical)


def l2_distance(a: npt.ArrayLike, b: npt.ArrayLike) -> F64:
    """(N, M) Euclidean distances between 3D centres."""
    pa, pb = _params(a, "a"), _params(b, "b")
    d = pa[:, None, X : Z + 1] - pb[None, :, X : Z + 1]
    return np.asarray(np.sqrt(np.einsum("nmk,nmk->nm", d, d)), dtype=np.float64)


def fold_yaw(d: F64) -> F64:
    """Fold yaw differences into (-pi/2, pi/2]: a box turned by pi has the same footprint."""
    return np.asarray(np.pi / 2 - np.mod(np.pi / 2 - d, np.pi), dtype=np.float64)


def mahalanobis(a: npt.ArrayLike, b: npt.ArrayLike, innovation: npt.ArrayLike) -> F64:
    """(N, M) ``sqrt(d^T S_j^-1 d)``, d = a_i - b_j (yaw folded), S (M, 7, 7) per column j."""
    pa, pb = _params(a, "a"), _params(b, "b")
    s = np.asarray(innovation, dtype=np.float64)
    if s.shape != (pb.shape[0], 7, 7):
        raise ValueError(f"innovation must be ({pb.shape[0]}, 7, 7), got {s.shape}")
    if pa.shape[0] == 0 or pb.shape[0] == 0:
        return np.zeros((pa.shape[0], pb.shape[0]))
    d = pa[:, None, :] - pb[None, :, :]
    d[..., YAW] = fold_yaw(d[..., YAW])
    s_inv = np.linalg.inv(s)
    q = np.einsum("nmi,nmi->nm", np.einsum("nmj,mij->nmi", d, s_inv), d)
    return np.asarray(np.sqrt(np.maximum(q, 0.0)), dtype=np.float64)


def distance_matrix(
    metric: Metric,
    dets: npt.ArrayLike,
    preds: npt.ArrayLike,
    *,
    vertical: VerticalOverlap = VerticalOverlap.EXACT,
    innovation: npt.ArrayLike | None = None,
) -> F64:
    """(N, M) association distances: ``1 - overlap`` for the IoU family, raw L2/Mahalanobis."""
    metric = Metric(metric)
    if metric is Metric.MAHALANOBIS:
        if innovation is None:
            raise ValueError("the mahalanobis metric needs the tracks' innovation covariances")
        return mahalanobis(dets, preds, innovation)
    if metric is Metric.L2:
        return l2_distance(dets, preds)
    overlap = {
        Metric.GIOU_3D: giou_3d,
        Metric.IOU_3D: iou_3d,
        Metric.GIOU_BEV: giou_bev,
        Metric.IOU_BEV: iou_bev,
    }[metric]
    return np.asarray(1.0 - overlap(dets, preds, vertical=vertical), dtype=np.float64)


def _overlap_pairs(
    pa: F64,
    pb: F64,
    ia: I64,
    ib: I64,
    *,
    three_d: bool,
    generalized: bool,
    vertical: VerticalOverlap,
) -> F64:
    """IoU or GIoU of the listed pairs only: the same arithmetic as ``_overlap`` per element."""
    a, b = pa[ia], pb[ib]
    reach = (np.hypot(a[:, L], a[:, W]) + np.hypot(b[:, L], b[:, W])) / 2
    d2 = np.square(a[:, X] - b[:, X]) + np.square(a[:, Y] - b[:, Y])
    near = np.flatnonzero(d2 <= reach * reach * (1.0 + _GATE_SLACK))
    inter = np.zeros(ia.size)
    if near.size:
        area = _intersection(a[near], b[near])
        inter[near] = np.clip(area, 0.0, np.minimum(_areas(a[near]), _areas(b[near])))
    size_a, size_b = _areas(a), _areas(b)
    overlap_h, union_h = _vertical(pa, pb, vertical, ia, ib) if three_d else (None, None)
    if three_d and overlap_h is not None:
        inter = inter * overlap_h
        size_a, size_b = size_a * a[:, H], size_b * b[:, H]
    union = size_a + size_b - inter
    reference_3d = three_d and vertical is VerticalOverlap.REFERENCE
    if reference_3d and not generalized:
        return np.asarray(inter / (union + _REFERENCE_EPS), dtype=np.float64)
    iou = np.divide(inter, union, out=np.zeros_like(inter), where=union > 0)
    if not generalized:
        return iou
    enclosing = _hull(a, b)
    if three_d and union_h is not None:
        enclosing = enclosing * union_h
    if not reference_3d:
        np.maximum(enclosing, union, out=enclosing)
    giou = np.divide(union, enclosing, out=np.ones_like(union), where=enclosing > 0)
    giou -= 1.0
    # Pairs that cannot intersect have IoU exactly 0, as in the dense path.
    giou[near] += iou[near]
    return giou


def distance_pairs(
    metric: Metric,
    dets: npt.ArrayLike,
    preds: npt.ArrayLike,
    det_index: npt.ArrayLike,
    pred_index: npt.ArrayLike,
    *,
    vertical: VerticalOverlap = VerticalOverlap.EXACT,
    innovation: npt.ArrayLike | None = None,
) -> F64:
    """Distances of the listed (det, pred) pairs: ``distance_matrix(...)[det_index, pred_index]``
    without computing the rest (e.g. only same-class pairs, all classes in one call)."""
    metric = Metric(metric)
    pa, pb = _params(dets, "dets"), _params(preds, "preds")
    ia = np.asarray(det_index, dtype=np.int64).reshape(-1)
    ib = np.asarray(pred_index, dtype=np.int64).reshape(-1)
    if ia.size != ib.size:
        raise ValueError(f"{ia.size} det indices but {ib.size} pred indices")
    if ia.size == 0:
        return np.zeros(0)
    if metric is Metric.L2:
        d = pa[ia, X : Z + 1] - pb[ib, X : Z + 1]
        return np.asarray(np.sqrt(np.einsum("pk,pk->p", d, d)), dtype=np.float64)
    if metric is Metric.MAHALANOBIS:
        if innovation is None:
            raise ValueError("the mahalanobis metric needs the tracks' innovation covariances")
        s_inv = np.linalg.inv(np.asarray(innovation, dtype=np.float64))
        d = pa[ia] - pb[ib]
        d[:, YAW] = fold_yaw(d[:, YAW])
        q = np.einsum("pi,pi->p", np.einsum("pj,pij->pi", d, s_inv[ib]), d)
        return np.asarray(np.sqrt(np.maximum(q, 0.0)), dtype=np.float64)
    three_d = metric in (Metric.GIOU_3D, Metric.IOU_3D)
    generalized = metric in (Metric.GIOU_3D, Metric.GIOU_BEV)
    overlap = _overlap_pairs(
        pa, pb, ia, ib, three_d=three_d, generalized=generalized, vertical=vertical
    )
    return np.asarray(1.0 - overlap, dtype=np.float64)
