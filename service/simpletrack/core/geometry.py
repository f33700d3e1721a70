"""Box geometry: BEV intersection and hull areas, IoU/GIoU, centre and Mahalanobis distances.

Every pairwise function takes ``a`` (N, 7) and ``b`` (M, 7) box parameters (x, y, z, yaw, l, w, h)
and returns a float64 (N, M) matrix, or values for listed pairs. The overlap measures are
computed pair by pair by the compiled kernels of core/overlap_kernels.py (its docstring has the
arithmetic: slab clipping with fixed slots and the shoelace formula for the intersection, a
closed form for the hull); this module validates the arguments and gates large frames.
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt

from simpletrack.core import overlap_kernels as kernels
from simpletrack.core.boxes import YAW, L, W, X, Y, Z
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
    "overlap_flags",
]

# Pairs per vectorised batch: bounds temporaries (tens of MB) whatever N x M is, while keeping
# the per-batch Python overhead negligible.
_CHUNK = 1 << 15
# The overlap gate's margin, shared with the kernels' own circle test.
_GATE_SLACK = kernels.GATE_SLACK

# Corner signs, counter-clockwise from front-left (+l/2, +w/2).
_SX = np.array([1.0, -1.0, -1.0, 1.0])
_SY = np.array([1.0, 1.0, -1.0, -1.0])


def _params(p: npt.ArrayLike, name: str) -> F64:
    # C order: the kernels are compiled for contiguous rows.
    arr = np.ascontiguousarray(p, dtype=np.float64)
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


def bev_intersection_area(a: npt.ArrayLike, b: npt.ArrayLike) -> F64:
    """(N, M) areas of the BEV footprints' intersections."""
    return kernels.intersection_matrix(_params(a, "a"), _params(b, "b"))


def bev_hull_area(a: npt.ArrayLike, b: npt.ArrayLike) -> F64:
    """(N, M) areas of the convex hulls of each pair's 8 BEV corners."""
    return kernels.hull_matrix(_params(a, "a"), _params(b, "b"))


def _overlap(
    a: npt.ArrayLike,
    b: npt.ArrayLike,
    *,
    three_d: bool,
    generalized: bool,
    vertical: VerticalOverlap,
) -> F64:
    exact = vertical is VerticalOverlap.EXACT
    return kernels.overlap_matrix(_params(a, "a"), _params(b, "b"), three_d, generalized, exact)


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
    ia, ib = _gate(pa, pb, ga, gb)
    exact = vertical is VerticalOverlap.EXACT
    return ia, ib, kernels.overlap_pairs(pa, pb, ia, ib, True, False, exact)


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


def overlap_flags(metric: Metric) -> tuple[bool, bool]:
    """(three_d, generalized) of an IoU-family metric, as the overlap kernels take them."""
    return metric in (Metric.GIOU_3D, Metric.IOU_3D), metric in (Metric.GIOU_3D, Metric.GIOU_BEV)


def _checked(index: I64, n: int, side: str) -> I64:
    """``index`` with numpy's negative indices resolved; IndexError outside -n..n-1."""
    lo, hi = int(index.min()), int(index.max())
    if lo < -n or hi >= n:
        raise IndexError(f"{side} index {lo if lo < -n else hi} is out of bounds for size {n}")
    return index if lo >= 0 else np.where(index < 0, index + n, index)


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
    ia = np.ascontiguousarray(det_index, dtype=np.int64).reshape(-1)
    ib = np.ascontiguousarray(pred_index, dtype=np.int64).reshape(-1)
    if ia.size != ib.size:
        raise ValueError(f"{ia.size} det indices but {ib.size} pred indices")
    if ia.size == 0:
        return np.zeros(0)
    # Compiled kernels do not check bounds: a bad index must fail here, not read memory.
    ia, ib = _checked(ia, pa.shape[0], "det"), _checked(ib, pb.shape[0], "pred")
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
    three_d, generalized = overlap_flags(metric)
    exact = vertical is VerticalOverlap.EXACT
    overlap = kernels.overlap_pairs(pa, pb, ia, ib, three_d, generalized, exact)
    return np.asarray(1.0 - overlap, dtype=np.float64)
