"""Compiled per-pair box overlap: BEV intersection and hull areas, IoU and GIoU (core/jit.py).

One pair at a time, in box a's own frame (a centred at the origin and axis-aligned):
coordinates stay small even kilometres from the world origin, and a's four half-planes become
the two slabs |u| <= l/2 and |v| <= w/2. Both areas are exact up to rounding (no tolerances,
no sorting, fixed slots):

- Intersection: b's outline clipped by a's two slabs. Each edge keeps three slots (its start,
  and the ends of its part inside the slab), clamped into the slab: an outside run then becomes
  a detour along the slab's boundary line, which encloses no area, so the shoelace formula over
  the 4 -> 12 -> 36 fixed slots gives the clipped area. Only pairs whose circumscribed circles
  meet are clipped (the same predicate as core/gate.py's overlap gate).
- Hull: the hull's support function is the max of both boxes' support functions h_a, h_b.
  Listing the hull's vertices as the winners at every edge normal n of either box and summing
  the shoelace terms collapses to a closed form:
      area(hull) = area(b) + sum over the 8 edges e of both boxes of |e|/2 * max(0, h_a(n_e) - h_b(n_e)).

The arithmetic (and its order) is that of the vectorised numpy code these kernels replaced;
helpers mirror numpy's fmin/fmax (NaN-skipping) and maximum/minimum (NaN-propagating). Every
division is guarded, so the uncompiled functions (SIMPLETRACK_JIT=0) raise nothing either.
"""

from __future__ import annotations

import math

import numpy as np
import numpy.typing as npt

from simpletrack.core.boxes import YAW, H, L, W, X, Y, Z
from simpletrack.core.jit import helper, inline, kernel

F64 = npt.NDArray[np.float64]
I64 = npt.NDArray[np.int64]

__all__ = ["hull_matrix", "intersection_matrix", "overlap_matrix", "overlap_pairs"]

# The reference code's iou3d divides by (U + 1e-5); reproduced in REFERENCE mode only.
REFERENCE_EPS = 1e-5
# Circle gate margin: pairs just outside it would clip to zero area anyway.
GATE_SLACK = 1e-9
_GATE_SCALE = 1.0 + GATE_SLACK

# Any layout in (each box's row is copied once into _with_terms), C order out.
_PAIRS = "float64[::1](float64[:, :], float64[:, :], int64[:], int64[:], boolean, boolean, boolean)"
_MATRIX_FLAGS = "float64[:, ::1](float64[:, :], float64[:, :], boolean, boolean, boolean)"
_MATRIX = "float64[:, ::1](float64[:, :], float64[:, :])"


@inline
def _fmin(a: float, b: float) -> float:
    if a != a:
        return b
    if b != b:
        return a
    return a if a <= b else b


@inline
def _fmax(a: float, b: float) -> float:
    if a != a:
        return b
    if b != b:
        return a
    return a if a >= b else b


@inline
def _maximum(a: float, b: float) -> float:
    return a if a >= b or a != a else b


@inline
def _minimum(a: float, b: float) -> float:
    return a if a <= b or a != a else b


@inline
def _recip(d: float) -> float:
    """1 / d, with IEEE's signed infinity for d = +-0 (Python itself would raise)."""
    if d == 0.0:
        return math.copysign(math.inf, d)
    return 1.0 / d


# Per-box terms appended to the 7 parameters (_with_terms): computed once per box, not per pair.
_COS, _SIN, _DIAG = 7, 8, 9


@helper
def _with_terms(p: F64) -> F64:
    """(N, 10): the parameters, then cos(yaw), sin(yaw) and the footprint's diagonal."""
    q = np.empty((p.shape[0], 10))
    for i in range(p.shape[0]):
        for c in range(7):
            q[i, c] = p[i, c]
        q[i, _COS], q[i, _SIN] = math.cos(p[i, YAW]), math.sin(p[i, YAW])
        q[i, _DIAG] = math.hypot(p[i, L], p[i, W])
    return q


@inline
def _relative(
    pa: F64, i: int, pb: F64, j: int, exact_yaw: bool
) -> tuple[float, float, float, float]:
    """b's centre (du, dv) and heading (cos, sin) in a's frame (rows of _with_terms arrays).
    ``exact_yaw`` takes cos/sin of the yaw difference (exactly 1, 0 for equal yaws); otherwise
    product formulas of per-box cos/sin (the hull's closed form needs no exact yaw)."""
    ca, sa = pa[i, _COS], pa[i, _SIN]
    if exact_yaw:
        dxw = pb[j, X] - pa[i, X]
        dyw = pb[j, Y] - pa[i, Y]
        dyaw = pb[j, YAW] - pa[i, YAW]
        return ca * dxw + sa * dyw, ca * dyw - sa * dxw, math.cos(dyaw), math.sin(dyaw)
    return _relative_of(pa[i, X], pa[i, Y], ca, sa, pb[j, X], pb[j, Y], pb[j, _COS], pb[j, _SIN])


@inline
def _relative_of(
    ax: float, ay: float, ca: float, sa: float, bx: float, by: float, cb: float, sb: float
) -> tuple[float, float, float, float]:
    """``_relative`` without exact_yaw, from the two boxes' centres and headings."""
    dxw = bx - ax
    dyw = by - ay
    c, s = cb * ca + sb * sa, sb * ca - cb * sa
    return ca * dxw + sa * dyw, ca * dyw - sa * dxw, c, s


@inline
def _clip_slab(u_in: F64, v_in: F64, n: int, h: float, u_out: F64, v_out: F64) -> None:
    """Clip the closed outline (u_in, v_in)[:n] to the slab |u| <= h into 3n slots: per edge
    its start, then the ends of its part inside the slab (Liang-Barsky parameters clamped to
    [0, 1]), all with u clamped into the slab."""
    for e in range(n):
        nxt = e + 1 if e + 1 < n else 0
        u, v = u_in[e], v_in[e]
        du, dv = u_in[nxt] - u, v_in[nxt] - v
        inv = _recip(du)
        t_lo = (-h - u) * inv
        t_hi = (h - u) * inv
        # fmin / fmax skip the NaN of 0 * inf (an edge lying along a boundary line).
        t0 = _fmax(_fmin(_fmin(t_lo, t_hi), 1.0), 0.0)
        t1 = _fmax(_fmin(_fmax(t_lo, t_hi), 1.0), 0.0)
        k = 3 * e
        u_out[k], v_out[k] = u, v
        u_out[k + 1], v_out[k + 1] = t0 * du + u, t0 * dv + v
        u_out[k + 2], v_out[k + 2] = t1 * du + u, t1 * dv + v
    for k in range(3 * n):
        u_out[k] = _minimum(_maximum(u_out[k], -h), h)


@helper
def _intersection(pa: F64, i: int, pb: F64, j: int, tmp: F64) -> float:
    """Raw BEV intersection area of boxes pa[i], pb[j]; ``tmp`` is (6, 36) scratch."""
    dx, dy, c, s = _relative(pa, i, pb, j, True)
    hl, hw = pb[j, L] / 2, pb[j, W] / 2
    ex, ey, fx, fy = c * hl, s * hl, -s * hw, c * hw
    # b's corners, counter-clockwise from front-left (+l/2, +w/2): signs (+,+) (-,+) (-,-) (+,-).
    x0, y0, x1, y1, x2, y2 = tmp[0], tmp[1], tmp[2], tmp[3], tmp[4], tmp[5]
    x0[0], y0[0] = dx + ex + fx, dy + ey + fy
    x0[1], y0[1] = dx + -ex + fx, dy + -ey + fy
    x0[2], y0[2] = dx + -ex + -fx, dy + -ey + -fy
    x0[3], y0[3] = dx + ex + -fx, dy + ey + -fy
    _clip_slab(x0, y0, 4, pa[i, L] / 2, x1, y1)
    _clip_slab(y1, x1, 12, pa[i, W] / 2, y2, x2)
    twice = x2[0] * y2[1] - x2[1] * y2[0]
    for k in range(1, 35):
        twice += x2[k] * y2[k + 1] - x2[k + 1] * y2[k]
    twice += x2[35] * y2[0] - x2[0] * y2[35]
    return float(0.5 * twice)


@inline
def _hull(pa: F64, i: int, pb: F64, j: int) -> float:
    """BEV convex hull area of boxes pa[i], pb[j] (closed form, see the module doc)."""
    dx, dy, c, s = _relative(pa, i, pb, j, False)
    return _hull_of(dx, dy, c, s, pa[i, L] / 2, pa[i, W] / 2, pb[j, L] / 2, pb[j, W] / 2)


@inline
def _hull_of(
    dx: float, dy: float, c: float, s: float, ha: float, wa: float, hl: float, hw: float
) -> float:
    """``_hull`` from b's centre and heading in a's frame and the four half sizes."""
    du, dv = abs(dx * c + dy * s), abs(dy * c - dx * s)  # b's centre along b's axes
    c, s, dx, dy = abs(c), abs(s), abs(dx), abs(dy)
    # Margins h_a - h_b along each edge normal, both boxes about their own centres: along a's
    # x and y, then along b's axis u and across it v. The centre offset d (>= 0) adds -d on one
    # side and +d on the other, and max(0, m - d) + max(0, m + d) = max(0, m + max(m, d)).
    mx = ha - (c * hl + s * hw)
    my = wa - (s * hl + c * hw)
    mu = ha * c + wa * s - hl
    mv = ha * s + wa * c - hw
    # Edge lengths: a's x normals 2 wa, y normals 2 ha; b's u normals 2 hw, v normals 2 hl.
    area = wa * _maximum(mx + _maximum(mx, dx), 0.0)
    area += ha * _maximum(my + _maximum(my, dy), 0.0)
    area += hw * _maximum(mu + _maximum(mu, du), 0.0)
    area += hl * _maximum(mv + _maximum(mv, dv), 0.0)
    area += 4.0 * hl * hw
    return float(area)


@inline
def _near(pa: F64, i: int, pb: F64, j: int) -> bool:
    """Whether the pair's circumscribed circles meet: only then can the footprints intersect."""
    reach = (pa[i, _DIAG] + pb[j, _DIAG]) / 2
    ddx, ddy = pa[i, X] - pb[j, X], pa[i, Y] - pb[j, Y]
    return bool(ddx * ddx + ddy * ddy <= reach * reach * _GATE_SCALE)


@helper
def _clipped_intersection(pa: F64, i: int, pb: F64, j: int, tmp: F64) -> float:
    """BEV intersection area clipped to [0, the smaller box's area]."""
    area = _intersection(pa, i, pb, j, tmp)
    cap = _minimum(pa[i, L] * pa[i, W], pb[j, L] * pb[j, W])
    return _minimum(_maximum(area, 0.0), cap)


@inline
def _vertical(za: float, ha: float, zb: float, hb: float, exact: bool) -> tuple[float, float]:
    """Overlap and union of two vertical extents (centre, height). Not ``exact``: the
    reference's formula, wrong when one extent contains the other."""
    top_a, bot_a = za + ha / 2, za - ha / 2
    top_b, bot_b = zb + hb / 2, zb - hb / 2
    if exact:
        return (
            _maximum(0.0, _minimum(top_a, top_b) - _maximum(bot_a, bot_b)),
            _maximum(top_a, top_b) - _minimum(bot_a, bot_b),
        )
    ab, ba = top_a - bot_b, top_b - bot_a
    return _maximum(0.0, _minimum(ab, ba)), _maximum(ab, ba)


@inline
def _union(
    inter: float,
    al: float,
    aw: float,
    az: float,
    ah: float,
    bl: float,
    bw: float,
    bz: float,
    bh: float,
    three_d: bool,
    exact_vertical: bool,
) -> tuple[float, float, float]:
    """(intersection, union, union height; 0 in BEV) of boxes a and b given by their sizes
    and heights, from the BEV intersection area."""
    size_a, size_b = al * aw, bl * bw
    union_h = 0.0
    if three_d:
        overlap_h, union_h = _vertical(az, ah, bz, bh, exact_vertical)
        inter = inter * overlap_h
        size_a, size_b = size_a * ah, size_b * bh
    return inter, size_a + size_b - inter, union_h


@inline
def _giou_less_iou(
    union: float, hull: float, union_h: float, three_d: bool, reference_3d: bool
) -> float:
    """GIoU - IoU = union / enclosing - 1."""
    enclosing = hull
    if three_d:
        enclosing = enclosing * union_h
    if not reference_3d:
        # The hull contains the union; rounding must not push GIoU above IoU.
        enclosing = _maximum(enclosing, union)
    giou = union / enclosing if enclosing > 0 else 1.0
    return giou - 1.0


Terms = tuple[float, float, float, float, float, float, float, float]


@inline
def _far_terms(p: F64, i: int) -> Terms:
    """The terms ``_far_giou`` reads of box p[i] (a ``_with_terms`` row), as values: a loop
    over many pairs keeps them in registers."""
    return p[i, X], p[i, Y], p[i, Z], p[i, L], p[i, W], p[i, H], p[i, _COS], p[i, _SIN]


@inline
def _far_giou(a: Terms, b: Terms, three_d: bool, exact_vertical: bool) -> float:
    """``_overlap``'s GIoU of a pair whose circles do not meet (``_near`` false), by the same
    operations in the same order, from the two boxes' ``_far_terms``."""
    ax, ay, az, al, aw, ah, ca, sa = a
    bx, by, bz, bl, bw, bh, cb, sb = b
    _, union, union_h = _union(0.0, al, aw, az, ah, bl, bw, bz, bh, three_d, exact_vertical)
    dx, dy, c, s = _relative_of(ax, ay, ca, sa, bx, by, cb, sb)
    hull = _hull_of(dx, dy, c, s, al / 2, aw / 2, bl / 2, bw / 2)
    return _giou_less_iou(union, hull, union_h, three_d, three_d and not exact_vertical)


@helper
def _overlap(
    pa: F64,
    i: int,
    pb: F64,
    j: int,
    three_d: bool,
    generalized: bool,
    exact_vertical: bool,
    tmp: F64,
) -> float:
    """IoU or GIoU (BEV or 3D) of boxes pa[i], pb[j]. The 3D reference mode (not
    ``exact_vertical``) uses the reference's vertical formulas and IoU = I / (U + 1e-5)."""
    near = _near(pa, i, pb, j)
    inter = 0.0
    if near:
        inter = _clipped_intersection(pa, i, pb, j, tmp)
    inter, union, union_h = _union(
        inter, pa[i, L], pa[i, W], pa[i, Z], pa[i, H], pb[j, L], pb[j, W], pb[j, Z], pb[j, H],
        three_d, exact_vertical,
    )  # fmt: skip
    reference_3d = three_d and not exact_vertical
    if reference_3d and not generalized:
        return float(inter / (union + REFERENCE_EPS))
    iou = inter / union if union > 0 else 0.0
    if not generalized:
        return iou
    giou = _giou_less_iou(union, _hull(pa, i, pb, j), union_h, three_d, reference_3d)
    # Pairs that cannot intersect have IoU exactly 0.
    if near:
        giou += iou
    return giou


@kernel(_PAIRS)
def overlap_pairs(
    pa: F64,
    pb: F64,
    ia: I64,
    ib: I64,
    three_d: bool,
    generalized: bool,
    exact_vertical: bool,
) -> F64:
    """IoU or GIoU of the listed pairs (pa[ia[k]], pb[ib[k]])."""
    out = np.empty(ia.size)
    pa, pb = _with_terms(pa), _with_terms(pb)
    tmp = np.empty((6, 36))  # scratch outlines, reused by every pair
    for k in range(ia.size):
        out[k] = _overlap(pa, ia[k], pb, ib[k], three_d, generalized, exact_vertical, tmp)
    return out


@kernel(_MATRIX_FLAGS)
def overlap_matrix(pa: F64, pb: F64, three_d: bool, generalized: bool, exact_vertical: bool) -> F64:
    """(N, M) IoU or GIoU of every pair: each entry as ``overlap_pairs`` computes it."""
    out = np.empty((pa.shape[0], pb.shape[0]))
    pa, pb = _with_terms(pa), _with_terms(pb)
    tmp = np.empty((6, 36))  # scratch outlines, reused by every pair
    for i in range(pa.shape[0]):
        for j in range(pb.shape[0]):
            out[i, j] = _overlap(pa, i, pb, j, three_d, generalized, exact_vertical, tmp)
    return out


@kernel(_MATRIX)
def intersection_matrix(pa: F64, pb: F64) -> F64:
    """(N, M) BEV intersection areas."""
    out = np.empty((pa.shape[0], pb.shape[0]))
    pa, pb = _with_terms(pa), _with_terms(pb)
    tmp = np.empty((6, 36))  # scratch outlines, reused by every pair
    for i in range(pa.shape[0]):
        for j in range(pb.shape[0]):
            near = _near(pa, i, pb, j)
            out[i, j] = _clipped_intersection(pa, i, pb, j, tmp) if near else 0.0
    return out


@kernel(_MATRIX)
def hull_matrix(pa: F64, pb: F64) -> F64:
    """(N, M) BEV convex hull areas, at least the larger box's area."""
    out = np.empty((pa.shape[0], pb.shape[0]))
    pa, pb = _with_terms(pa), _with_terms(pb)
    for i in range(pa.shape[0]):
        for j in range(pb.shape[0]):
            hull = _hull(pa, i, pb, j)
            out[i, j] = _maximum(hull, _maximum(pa[i, L] * pa[i, W], pb[j, L] * pb[j, W]))
    return out
