"""Compiled stage-1 assignment of a dense frame: every class's block solved in one call.

``lsap`` is the rectangular linear sum assignment by shortest augmenting paths (D. F. Crouse,
"On implementing 2D rectangular assignment algorithms", IEEE TAES 52(4), 2016), with the
choices that make scipy.optimize.linear_sum_assignment's answer unique among optima: costs
taken as given (no shift), rows added in order, the free columns scanned from the last, ties
of the lowest reduced cost going to an unassigned column; a wide problem is solved transposed
and its pairs listed by row. tests/core/test_assignment_kernels.py holds it equal to scipy.

``stage1_dense`` is ``Tracker._stage1`` on a dense table: class by class, the block of the
class's candidates against its tracks, optionally with a threshold per track (gate widening),
solved by ``lsap`` (Hungarian) or the greedy walk, matches over the threshold rejected; the
output order is the Python code's (association.py's ``_finish``).
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt

from simpletrack.core.jit import helper, kernel

F64 = npt.NDArray[np.float64]
I64 = npt.NDArray[np.int64]

__all__ = ["INFEASIBLE", "lsap", "stage1_dense"]

# lsap's answer when no full assignment has a finite cost (scipy raises ValueError).
INFEASIBLE = -1

_LSAP = "Tuple((int64[::1], int64[::1], int64))(float64[:, :])"
_STAGE1 = (
    "Tuple((int64[::1], int64[::1], int64[::1], int64))"
    "(float64[:, :], int64[:], int64[:], int64[:], int64[:], int64[:],"
    " float64[:], boolean[:], boolean[:], float64[:], float64[:])"
)


@helper
def _solve(cost: F64, col4row: I64) -> int:
    """Rows <= columns: ``col4row`` filled with each row's column; INFEASIBLE or 0."""
    nr, nc = cost.shape
    u = np.zeros(nr)
    v = np.zeros(nc)
    spc = np.empty(nc)  # shortest path costs
    path = np.full(nc, -1, dtype=np.int64)
    row4col = np.full(nc, -1, dtype=np.int64)
    col4row[:] = -1
    sr = np.zeros(nr, dtype=np.bool_)
    sc = np.zeros(nc, dtype=np.bool_)
    remaining = np.empty(nc, dtype=np.int64)
    for cur in range(nr):
        for it in range(nc):
            remaining[it] = nc - it - 1
        n_rem = nc
        sr[:] = False
        sc[:] = False
        spc[:] = np.inf
        min_val = 0.0
        i = cur
        sink = -1
        while sink == -1:
            index = -1
            lowest = np.inf
            sr[i] = True
            for it in range(n_rem):
                j = remaining[it]
                r = min_val + cost[i, j] - u[i] - v[j]
                if r < spc[j]:
                    path[j] = i
                    spc[j] = r
                if spc[j] < lowest or (spc[j] == lowest and row4col[j] == -1):
                    lowest = spc[j]
                    index = it
            min_val = lowest
            if index == -1 or min_val == np.inf:
                return INFEASIBLE
            j = remaining[index]
            if row4col[j] == -1:
                sink = j
            else:
                i = row4col[j]
            sc[j] = True
            n_rem -= 1
            remaining[index] = remaining[n_rem]
        u[cur] += min_val
        for i in range(nr):
            if sr[i] and i != cur:
                u[i] += min_val - spc[col4row[i]]
        for j in range(nc):
            if sc[j]:
                v[j] -= min_val - spc[j]
        j = sink
        while True:
            i = path[j]
            row4col[j] = i
            col4row[i], j = j, col4row[i]
            if i == cur:
                break
    return 0


@kernel(_LSAP)
def lsap(cost: F64) -> tuple[I64, I64, int]:
    """(rows, cols, status) of the optimal assignment, rows ascending, as scipy lists it.
    status INFEASIBLE (and no pairs) for NaN, -inf, or no full assignment of finite cost."""
    return _assignment(cost)


@helper
def _assignment(cost: F64) -> tuple[I64, I64, int]:
    """``lsap``'s body, callable from other kernels."""
    nr, nc = cost.shape
    empty = np.zeros(0, dtype=np.int64)
    if nr == 0 or nc == 0:
        return empty, empty.copy(), 0
    wide = nr > nc
    c = cost.T.copy() if wide else cost.copy()
    # No shift by the minimum: scipy (1.17) solves the costs as given, and a shift rounds
    # large costs differently (other optima win their ties).
    finite = False
    for x in c.ravel():
        if x != x or x == -np.inf:
            return empty, empty.copy(), INFEASIBLE
        finite = finite or x != np.inf
    if not finite:
        return empty, empty.copy(), INFEASIBLE
    n = c.shape[0]
    col4row = np.empty(n, dtype=np.int64)
    if _solve(c, col4row) == INFEASIBLE:
        return empty, empty.copy(), INFEASIBLE
    seq = np.arange(n, dtype=np.int64)
    if not wide:
        return seq, col4row, 0
    order = np.argsort(col4row, kind="mergesort")
    return col4row[order].copy(), seq[order].copy(), 0


@helper
def _greedy(block: F64, limit: float, rows: I64, cols: I64) -> int:
    """The greedy walk (association._greedy_walk): pairs within ``limit`` by ascending
    distance, ties in row-major order, each taken when both sides are free. Pairs into
    ``rows``/``cols`` in walk order; returns their count."""
    n, m = block.shape
    cand = 0
    for i in range(n):
        for j in range(m):
            if block[i, j] <= limit:
                cand += 1
    d = np.empty(cand)
    ci = np.empty(cand, dtype=np.int64)
    cj = np.empty(cand, dtype=np.int64)
    k = 0
    for i in range(n):
        for j in range(m):
            if block[i, j] <= limit:
                d[k], ci[k], cj[k] = block[i, j], i, j
                k += 1
    order = np.argsort(d, kind="mergesort")
    det_free = np.ones(n, dtype=np.bool_)
    trk_free = np.ones(m, dtype=np.bool_)
    count = 0
    for o in order:
        r, c = ci[o], cj[o]
        if det_free[r] and trk_free[c]:
            det_free[r] = False
            trk_free[c] = False
            rows[count], cols[count] = r, c
            count += 1
            if count == min(n, m):
                break
    return count


@kernel(_STAGE1)
def stage1_dense(
    matrix: F64,
    codes: I64,
    cand: I64,
    cand_rows: I64,
    cand_cls: I64,
    trk_cls: I64,
    max_distance: F64,
    hungarian: npt.NDArray[np.bool_],
    widened: npt.NDArray[np.bool_],
    reach: F64,
    far_cost: F64,
) -> tuple[I64, I64, I64, int]:
    """(matched det, matched track, unmatched det, status) over the classes ``codes`` in
    order; ``cand`` are the candidates' detection indices, ``cand_rows`` their rows of
    ``matrix``; status INFEASIBLE when a Hungarian block has no finite full assignment (the
    caller then runs the Python path, which raises as scipy does)."""
    md = np.empty(cand.size, dtype=np.int64)
    mt = np.empty(cand.size, dtype=np.int64)
    um = np.empty(cand.size, dtype=np.int64)
    n_md = 0
    n_um = 0
    for code in codes:
        d_sel = np.flatnonzero(cand_cls == code)
        t_sel = np.flatnonzero(trk_cls == code)
        n, m = d_sel.size, t_sel.size
        block = np.empty((n, m))
        for a in range(n):
            for b in range(m):
                block[a, b] = matrix[cand_rows[d_sel[a]], t_sel[b]]
        limit = max_distance[code]
        if widened[code]:
            limit = 0.0
            for b in range(m):
                limit = max(limit, reach[t_sel[b]])
            for a in range(n):
                for b in range(m):
                    if not block[a, b] <= reach[t_sel[b]]:
                        block[a, b] = far_cost[code]
        rows = np.empty(min(n, m), dtype=np.int64)
        cols = np.empty(min(n, m), dtype=np.int64)
        if hungarian[code]:
            count = 0
            if n > 0 and m > 0:
                r, c, status = _assignment(block)
                if status == INFEASIBLE:
                    return md[:0].copy(), mt[:0].copy(), um[:0].copy(), INFEASIBLE
                count = r.size
                rows[:count], cols[:count] = r, c
        else:
            count = _greedy(block, limit, rows, cols)
        assigned = np.zeros(n, dtype=np.bool_)
        for k in range(count):
            assigned[rows[k]] = True
        for k in range(count):
            if block[rows[k], cols[k]] <= limit:
                md[n_md], mt[n_md] = cand[d_sel[rows[k]]], t_sel[cols[k]]
                n_md += 1
        for a in range(n):
            if not assigned[a]:
                um[n_um] = cand[d_sel[a]]
                n_um += 1
        for k in range(count):
            if not block[rows[k], cols[k]] <= limit:
                um[n_um] = cand[d_sel[rows[k]]]
                n_um += 1
    return md[:n_md].copy(), mt[:n_md].copy(), um[:n_um].copy(), 0
