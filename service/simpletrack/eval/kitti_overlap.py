"""Pairwise overlaps of KITTI camera-frame boxes, vectorised over pairs.

The evaluator scores sparse (ground truth, tracker) pairs of the same frame, so these take two
aligned arrays of P boxes each and return P values, rather than an (N, M) matrix.
Camera boxes are rows ``h, w, l, x, y, z, rot_y`` (KITTI order): ``(x, y, z)`` is the centre of
the bottom face, y points down, ``rot_y`` turns the box about the y axis.
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt

F64 = npt.NDArray[np.float64]

H, W, L, X, Y, Z, RY = range(7)

# Corner offsets along the box's own length and width axes, in order around the rectangle.
_ALONG_L = np.array([0.5, 0.5, -0.5, -0.5])
_ALONG_W = np.array([0.5, -0.5, -0.5, 0.5])


def bev_corners(cam: F64) -> F64:
    """(P, 4, 2) corners of the boxes' footprints in the camera x-z plane, as AB3DMOT draws them
    (``roty(rot_y) @ [x, z]`` with the length along the box's x axis)."""
    c, s = np.cos(cam[:, RY])[:, None], np.sin(cam[:, RY])[:, None]
    dl = cam[:, L, None] * _ALONG_L
    dw = cam[:, W, None] * _ALONG_W
    x = c * dl + s * dw + cam[:, X, None]
    z = -s * dl + c * dw + cam[:, Z, None]
    return np.stack([x, z], axis=-1)


def _cross(a: F64, b: F64) -> F64:
    return np.asarray(a[..., 0] * b[..., 1] - a[..., 1] * b[..., 0], dtype=np.float64)


def _inside(points: F64, poly: F64, tol: F64) -> npt.NDArray[np.bool_]:
    """(P, K) whether each point lies in (or on) its convex quadrilateral, either winding."""
    edges = np.roll(poly, -1, axis=1) - poly  # (P, 4, 2)
    rel = points[:, :, None, :] - poly[:, None, :, :]  # (P, K, 4, 2)
    side = _cross(edges[:, None, :, :], rel)  # (P, K, 4)
    t = tol[:, None, None]
    return np.asarray((side >= -t).all(axis=-1) | (side <= t).all(axis=-1))


def convex_quad_intersection_area(a: F64, b: F64) -> F64:
    """Area of the intersection of P pairs of convex quadrilaterals (P, 4, 2) each.

    The intersection polygon's vertices are the corners of each quad inside the other plus the
    crossing points of their edges; sorted by angle about their mean they close the polygon."""
    p = a.shape[0]
    if p == 0:
        return np.zeros(0)
    scale = np.maximum(np.abs(a).max(axis=(1, 2)), np.abs(b).max(axis=(1, 2))) + 1.0
    tol = 1e-9 * scale * scale
    ea = np.roll(a, -1, axis=1) - a
    eb = np.roll(b, -1, axis=1) - b
    # Edge i of a against edge j of b: a_i + t ea_i == b_j + u eb_j.
    r = ea[:, :, None, :]
    s = eb[:, None, :, :]
    qp = b[:, None, :, :] - a[:, :, None, :]
    denom = _cross(r, s)
    safe = np.where(np.abs(denom) > tol[:, None, None], denom, 1.0)
    t = _cross(qp, s) / safe
    u = _cross(qp, r) / safe
    eps = 1e-12
    hit = (np.abs(denom) > tol[:, None, None]) & (t >= -eps) & (t <= 1 + eps)
    hit &= (u >= -eps) & (u <= 1 + eps)
    crossings = a[:, :, None, :] + t[..., None] * r  # (P, 4, 4, 2)

    pts = np.concatenate([a, b, crossings.reshape(p, 16, 2)], axis=1)  # (P, 24, 2)
    valid = np.concatenate([_inside(a, b, tol), _inside(b, a, tol), hit.reshape(p, 16)], axis=1)
    count = valid.sum(axis=1)
    centre = (pts * valid[..., None]).sum(axis=1) / np.maximum(count, 1)[:, None]
    rel = pts - centre[:, None, :]
    angle = np.where(valid, np.arctan2(rel[..., 1], rel[..., 0]), np.inf)
    order = np.argsort(angle, axis=1)
    ring = np.take_along_axis(rel, order[..., None], axis=1)
    # Unused slots repeat the first vertex: their edges have zero cross product.
    slot = np.arange(ring.shape[1])[None, :]
    ring = np.where((slot < count[:, None])[..., None], ring, ring[:, :1, :])
    area = 0.5 * np.abs(_cross(ring, np.roll(ring, -1, axis=1)).sum(axis=1))
    return np.asarray(np.where(count >= 3, area, 0.0), dtype=np.float64)


def iou3d_pairs(a: F64, b: F64) -> F64:
    """3D IoU of P aligned pairs of camera boxes (P, 7): footprint overlap in x-z times the
    exact vertical overlap (each box spans y - h .. y), over the union of the volumes."""
    if a.shape[0] == 0:
        return np.zeros(0)
    ca, cb = bev_corners(a), bev_corners(b)
    area = convex_quad_intersection_area(ca, cb)
    top = np.maximum(a[:, Y] - a[:, H], b[:, Y] - b[:, H])
    bottom = np.minimum(a[:, Y], b[:, Y])
    inter = area * np.maximum(bottom - top, 0.0)
    vol_a = a[:, H] * a[:, W] * a[:, L]
    vol_b = b[:, H] * b[:, W] * b[:, L]
    union = vol_a + vol_b - inter
    return np.asarray(np.where(union > 0, inter / np.where(union > 0, union, 1.0), 0.0))


def footprints_may_touch(a: F64, b: F64) -> npt.NDArray[np.bool_]:
    """Cheap pre-filter: False where the pair's footprints are certainly apart."""
    reach = 0.5 * (np.hypot(a[:, L], a[:, W]) + np.hypot(b[:, L], b[:, W]))
    dist = np.hypot(a[:, X] - b[:, X], a[:, Z] - b[:, Z])
    return np.asarray(dist <= reach + 1e-9)


def box2d_overlap_own_area(a: F64, b: F64) -> F64:
    """Intersection of 2D boxes (P, 4) ``x1 y1 x2 y2`` over the area of ``a`` (0 when disjoint),
    as the KITTI devkit's ``boxoverlap(a, b, "a")``."""
    w = np.minimum(a[:, 2], b[:, 2]) - np.maximum(a[:, 0], b[:, 0])
    h = np.minimum(a[:, 3], b[:, 3]) - np.maximum(a[:, 1], b[:, 1])
    area = (a[:, 2] - a[:, 0]) * (a[:, 3] - a[:, 1])
    touching = (w > 0) & (h > 0)
    safe = np.where(touching & (area != 0), area, 1.0)
    return np.asarray(np.where(touching, w * h / safe, 0.0), dtype=np.float64)
