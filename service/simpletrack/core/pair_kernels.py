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

from simpletrack.core.jit import kernel
from simpletrack.core.overlap_kernels import _overlap, _with_terms

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


@kernel(_TABLE)
def class_table(
    d_params: F64, d_cls: I64, t_params: F64, t_cls: I64, kind: I64, exact_vertical: bool
) -> F64:
    """(N, M): ``1 - overlap`` of each same-class pair whose class ``kind`` is an overlap
    metric (``overlap_kind``), +inf for every other pair."""
    out = np.full((d_params.shape[0], t_params.shape[0]), np.inf)
    if out.size == 0:
        return out
    pa, pb = _with_terms(d_params), _with_terms(t_params)
    tmp = np.empty((6, 36))  # scratch outlines, reused by every pair
    for i in range(d_params.shape[0]):
        c = d_cls[i]
        k = kind[c]
        if k == NOT_OVERLAP:
            continue
        three_d, generalized = (k & _THREE_D) != 0, (k & _GENERALIZED) != 0
        for j in range(t_params.shape[0]):
            if t_cls[j] == c:
                o = _overlap(pa, i, pb, j, three_d, generalized, exact_vertical, tmp)
                out[i, j] = 1.0 - o
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
            if not suppressed[j] and _overlap(p, i, p, j, True, False, exact_vertical, tmp) > limit:
                suppressed[j] = True
    return kept[:count].copy()
