"""Compiled pair loops of the calibration monitor (core/calibration.py, core/jit.py).

A camera frame meets every trusted track: the vectorised version built (N, M, 2) offset
tables and a dozen temporaries per frame (0.3 ms of a fused camera frame's 1 ms on
nuScenes-sized frames). These walk the same pairs once, in the same order, with the same
rules: a pair votes when its classes match and both offsets are under ``search`` metres; the
time fit takes mutual nearest same-class pairs (first index on ties, as ``argmin``). The
votes' grid (``offset_votes``: ~15 numpy calls on a 60 x 60 grid, ~40 µs a camera frame) is
one pass too, its sums in numpy's order, so its figures are the numpy code's bit for bit.
"""

from __future__ import annotations

import math

import numpy as np
import numpy.typing as npt

from simpletrack.core.jit import helper, kernel

F64 = npt.NDArray[np.float64]
I32 = npt.NDArray[np.int32]

__all__ = ["offset_votes", "time_fit", "voting_pairs"]

_XY = "float64[:, :]"
_CLS = "int32[:]"


@kernel(f"float64[:, ::1]({_XY}, {_CLS}, {_XY}, {_CLS}, float64)")
def voting_pairs(det: F64, det_cls: I32, trk: F64, trk_cls: I32, search: float) -> F64:
    """The (dx, dy) offsets (detection minus track) of every same-class pair closer than
    ``search`` on both axes, detection-major as the vectorised table's boolean mask."""
    n, m = det.shape[0], trk.shape[0]
    out = np.empty((n * m, 2))
    k = 0
    for i in range(n):
        for j in range(m):
            if det_cls[i] != trk_cls[j]:
                continue
            dx = det[i, 0] - trk[j, 0]
            dy = det[i, 1] - trk[j, 1]
            if abs(dx) < search and abs(dy) < search:
                out[k, 0] = dx
                out[k, 1] = dy
                k += 1
    return out[:k].copy()


@kernel(f"float64[::1]({_XY}, {_CLS}, {_XY}, {_XY}, {_CLS}, float64, float64, float64)")
def time_fit(
    det: F64, det_cls: I32, trk: F64, trk_vel: F64, trk_cls: I32, shift_x: float,
    shift_y: float, gate: float,
) -> F64:  # fmt: skip
    """The normal equations of ``residual = b + v * delta`` over the mutual nearest same-class
    pairs within ``gate`` once the shift is taken out: 9 of the (3, 3) matrix, 3 of the right
    side, then (y'y, rows)."""
    n, m = det.shape[0], trk.shape[0]
    out = np.zeros(14)
    if n == 0 or m == 0:
        return out
    best_t = np.zeros(n, dtype=np.int64)
    best_t_d = np.full(n, np.inf)
    best_d = np.zeros(m, dtype=np.int64)
    best_d_d = np.full(m, np.inf)
    for i in range(n):
        for j in range(m):
            if det_cls[i] != trk_cls[j]:
                continue
            d = math.hypot(det[i, 0] - trk[j, 0] - shift_x, det[i, 1] - trk[j, 1] - shift_y)
            if d < best_t_d[i]:
                best_t_d[i] = d
                best_t[i] = j
            if d < best_d_d[j]:
                best_d_d[j] = d
                best_d[j] = i
    ata = np.zeros((3, 3))
    aty = np.zeros(3)
    yy = 0.0
    rows = 0.0
    for i in range(n):
        j = best_t[i]
        if best_d[j] != i or not best_t_d[i] <= gate:
            continue
        rx = det[i, 0] - trk[j, 0]  # the offset left in: b is fitted
        ry = det[i, 1] - trk[j, 1]
        vx = trk_vel[j, 0]
        vy = trk_vel[j, 1]
        # Rows (1, 0, vx) -> rx and (0, 1, vy) -> ry.
        ata[0, 0] += 1.0
        ata[1, 1] += 1.0
        ata[0, 2] += vx
        ata[1, 2] += vy
        ata[2, 2] += vx * vx + vy * vy
        aty[0] += rx
        aty[1] += ry
        aty[2] += vx * rx + vy * ry
        yy += rx * rx + ry * ry
        rows += 2.0
    ata[2, 0] = ata[0, 2]
    ata[2, 1] = ata[1, 2]
    for a in range(3):
        for b in range(3):
            out[3 * a + b] = ata[a, b]
        out[9 + a] = aty[a]
    out[12] = yy
    out[13] = rows
    return out


@helper
def _region(votes: F64, i: int, j: int) -> float:
    """The votes in the 3 x 3 cells around (i, j), summed as numpy sums that slice: the cells
    in row order into one buffer, then its pairwise sum (below eight values one after
    another; nine: eight partial sums paired, then the ninth), added to 0."""
    bins = votes.shape[0]
    buf = np.empty(9)
    n = 0
    for a in range(max(i - 1, 0), min(i + 2, bins)):
        for b in range(max(j - 1, 0), min(j + 2, votes.shape[1])):
            buf[n] = votes[a, b]
            n += 1
    if n < 8:
        res = -0.0
        for k in range(n):
            res += buf[k]
    else:
        res = ((buf[0] + buf[1]) + (buf[2] + buf[3])) + ((buf[4] + buf[5]) + (buf[6] + buf[7]))
        for k in range(8, n):
            res += buf[k]
    return 0.0 + res


@kernel("Tuple((float64[:, ::1], float64[::1]))(float64[:, ::1], float64[:, :], float64, float64)")
def offset_votes(
    off: F64, before: F64, decay: float, bin_m: float
) -> tuple[F64, F64]:  # fmt: skip
    """The votes after one frame's pair offsets ``off`` (``before`` decayed, plus one per
    pair in its cell) and what ``calibration.observe`` reads of them, as its numpy did: (peak
    cell i, j, the votes around it, around (0, 0), pairs in the peak's region, their mean dx,
    dy, this frame's own peak cell i, j and its votes around (0, 0))."""
    bins = before.shape[0]
    centre = bins // 2
    k = off.shape[0]
    cells = np.empty((k, 2), dtype=np.int64)
    frame = np.zeros((bins, bins))
    for p in range(k):
        cx = np.int64(math.floor(off[p, 0] / bin_m)) + centre
        cy = np.int64(math.floor(off[p, 1] / bin_m)) + centre
        cells[p, 0] = cx
        cells[p, 1] = cy
        frame[cx, cy] += 1.0
    votes = np.empty((bins, bins))
    pi, pj, fi, fj = 0, 0, 0, 0
    for a in range(bins):
        for b in range(bins):
            v = before[a, b] * decay + frame[a, b]
            votes[a, b] = v
            if v > votes[pi, pj]:  # the first of equal maxima, as argmax
                pi, pj = a, b
            if frame[a, b] > frame[fi, fj]:
                fi, fj = a, b
    sx, sy, sel = 0.0, 0.0, 0
    for p in range(k):
        if abs(cells[p, 0] - pi) <= 1 and abs(cells[p, 1] - pj) <= 1:
            sx += off[p, 0]
            sy += off[p, 1]
            sel += 1
    out = np.empty(10)
    out[0], out[1] = pi, pj
    out[2] = _region(votes, pi, pj)
    out[3] = _region(votes, centre, centre) + _region(votes, centre - 1, centre - 1)
    out[4] = sel
    out[5] = sx / sel if sel else 0.0
    out[6] = sy / sel if sel else 0.0
    out[7], out[8] = fi, fj
    out[9] = _region(frame, centre, centre) + _region(frame, centre - 1, centre - 1)
    return votes, out
