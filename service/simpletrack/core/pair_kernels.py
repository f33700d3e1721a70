"""Compiled walks over a frame's same-class pairs: the association table and the NMS walk.

Both evaluate each pair with core/overlap_kernels.py's per-pair arithmetic (``_overlap``), so
every value is the one the vectorised path computes; what they save is the numpy machinery
around it (class masks, index lists, fancy-index scatters), which cost more than the pairs.

- ``class_table``: the dense (N, M) distance table of ``Tracker._dense_table`` for the classes
  whose metric is of the IoU family (``1 - overlap``, +inf across classes); classes measured
  by L2 or Mahalanobis are left +inf here and filled by the caller.
- ``nms_walk``: greedy NMS over boxes listed class by class in score order. A kept box's IoU
  is computed only with the boxes of its class not yet visited nor suppressed: the decisions
  are those of the all-pairs walk (a visited box is never re-decided), with fewer pairs.
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt

from simpletrack.core.jit import helper, kernel
from simpletrack.core.overlap_kernels import (
    _far_giou,
    _far_terms,
    _near,
    _overlap,
    _with_terms,
)

F64 = npt.NDArray[np.float64]
I64 = npt.NDArray[np.int64]

__all__ = ["NOT_OVERLAP", "class_table", "nms_walk", "overlap_kind"]

# A class's metric as the kernels read it: bit 0 three_d, bit 1 generalized; NOT_OVERLAP for
# L2 and Mahalanobis (left to numpy).
NOT_OVERLAP = -1
_THREE_D, _GENERALIZED = 1, 2

_TABLE = "float64[:, ::1](float64[:, :], int64[:], float64[:, :], int64[:], int64[:], boolean)"
_WALK = "int64[::1](float64[:, :], int64[:], int64[:], float64[:], boolean)"


def overlap_kind(three_d: bool, generalized: bool) -> int:
    return (_THREE_D if three_d else 0) | (_GENERALIZED if generalized else 0)


@helper
def _by_class(cls: I64, n_cls: int) -> tuple[I64, I64]:
    """(order, start): indices listed class by class, ascending within a class (a counting
    sort); class c's are order[start[c]:start[c + 1]]."""
    start = np.zeros(n_cls + 1, dtype=np.int64)
    for j in range(cls.shape[0]):
        start[cls[j] + 1] += 1
    for c in range(n_cls):
        start[c + 1] += start[c]
    order = np.empty(cls.shape[0], dtype=np.int64)
    fill = start[:-1].copy()
    for j in range(cls.shape[0]):
        order[fill[cls[j]]] = j
        fill[cls[j]] += 1
    return order, start


@kernel(_TABLE)
def class_table(
    d_params: F64, d_cls: I64, t_params: F64, t_cls: I64, kind: I64, exact_vertical: bool
) -> F64:
    """(N, M): ``1 - overlap`` of each same-class pair whose class ``kind`` is an overlap
    metric (``overlap_kind``), +inf for every other pair. A GIoU row is computed for all of
    the class's tracks at once as if no pair met (``_far_giou``, over columns of the tracks'
    terms: a loop without calls), then the pairs whose circles meet are redone whole."""
    out = np.full((d_params.shape[0], t_params.shape[0]), np.inf)
    if out.size == 0:
        return out
    pa, pb = _with_terms(d_params), _with_terms(t_params)
    tmp = np.empty((6, 36))  # scratch outlines, reused by every pair
    order, start = _by_class(t_cls, kind.shape[0])
    tb = np.empty((8, order.size))  # the tracks' _far_terms as columns, in class order
    for s in range(order.size):
        tb[:, s] = _far_terms(pb, order[s])
    far = np.empty(t_params.shape[0])
    for i in range(d_params.shape[0]):
        c = d_cls[i]
        k = kind[c]
        if k == NOT_OVERLAP:
            continue
        three_d, generalized = (k & _THREE_D) != 0, (k & _GENERALIZED) != 0
        lo, hi = start[c], start[c + 1]
        if generalized:
            a = _far_terms(pa, i)
            for s in range(lo, hi):
                b = (tb[0, s], tb[1, s], tb[2, s], tb[3, s], tb[4, s], tb[5, s], tb[6, s], tb[7, s])
                far[s] = 1.0 - _far_giou(a, b, three_d, exact_vertical)
        for s in range(lo, hi):
            j = order[s]
            if generalized and not _near(pa, i, pb, j):
                out[i, j] = far[s]
            else:
                out[i, j] = 1.0 - _overlap(pa, i, pb, j, three_d, generalized, exact_vertical, tmp)
    return out


@kernel(_WALK)
def nms_walk(params: F64, cls: I64, order: I64, threshold: F64, exact_vertical: bool) -> I64:
    """Kept indices, in walk order: ``order`` lists boxes class by class (each class's boxes
    contiguous), best first; a box is suppressed when its 3D IoU with a kept box of its class
    (computed with the kept box as the first argument) is over ``threshold[class]``."""
    n = order.size
    kept = np.empty(n, dtype=np.int64)
    if n == 0:
        return kept
    p = _with_terms(params)
    tmp = np.empty((6, 36))
    suppressed = np.zeros(params.shape[0], dtype=np.bool_)
    count = 0
    for a in range(n):
        i = order[a]
        if suppressed[i]:
            continue
        kept[count] = i
        count += 1
        c = cls[i]
        limit = threshold[c]
        for b in range(a + 1, n):
            j = order[b]
            if cls[j] != c:
                break
            # A pair whose circles do not meet has IoU 0 (or NaN): over no threshold >= 0.
            if suppressed[j] or (limit >= 0.0 and not _near(p, i, p, j)):
                continue
            if _overlap(p, i, p, j, True, False, exact_vertical, tmp) > limit:
                suppressed[j] = True
    return kept[:count].copy()
