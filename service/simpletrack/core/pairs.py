"""The (detection, track) distance table as a list of pairs, and when a class is solved dense.

Why two regimes. A greedy match and stage 2 only ever look at pairs within their thresholds,
so the exact gate (core/gate.py) changes nothing for them. The Hungarian optimum over the full
matrix, though, can depend on what pairs beyond the threshold cost: with detections A, B and
tracks 1, 2, d(A,1) = 1.0, d(B,1) = 1.4 (both within 1.5) and d(A,2) = 1.51, d(B,2) = 1.99
(both beyond), the full optimum A-2 + B-1 (2.91 < 2.99) keeps B-1, while a solve that never
sees the pairs beyond the threshold keeps A-1. No cheap bound can stand in for those costs,
so a class block of at most ``DENSE_CELLS`` pairs is computed and solved in full, exactly as
before (every nuScenes and KITTI frame: their largest blocks are a few thousand pairs), and
only a larger block uses the gated pairs with every other pair costing ``far_cost``
(association.sparse_hungarian): what a pair beyond the gate costs when its boxes are far
apart (IoU: exactly 1; GIoU: just under 2).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from simpletrack.core.config import ClassConfig, Metric

F64 = npt.NDArray[np.float64]
I64 = npt.NDArray[np.int64]

# Largest (detections x tracks) block of one class solved dense. nuScenes' largest is about
# 9,000 pairs, KITTI's far less; 2^16 pairs cost some 40 ms of distances and a 0.5 MB matrix
# (a 1,000-box frame: 43 ms with it, 200 ms with 2^18; service/simpletrack/bench/heavy.py),
# so the dense path never holds a worker long; past it cost grows with the gated pairs.
DENSE_CELLS = 1 << 16

# The supremum of each bounded metric's distance: 1 - IoU <= 1, 1 - GIoU < 2.
_RANGE = {Metric.IOU_3D: 1.0, Metric.IOU_BEV: 1.0, Metric.GIOU_3D: 2.0, Metric.GIOU_BEV: 2.0}


def far_cost(c: ClassConfig) -> float:
    """Cost of an unlisted pair in a gated Hungarian solve: the metric's range where the
    widest stage-1 threshold is inside it (far pairs cost about that), else twice that
    threshold; either way more than any pair a stage-1 threshold accepts."""
    reach = c.widest_max_distance
    top = _RANGE.get(c.metric)
    if top is not None and reach < top:
        return top
    return 2.0 * reach


@dataclass(frozen=True, slots=True)
class PairTable:
    """Listed (detection row, track) pairs, row-major, with their distances; pairs not listed
    are of different classes or, in a gated class (``dense[code]`` false), provably beyond
    both stages' thresholds. An ordinary frame (every class dense) carries the full
    (detections, tracks) ``matrix`` instead (other classes +inf), as it always did."""

    rows: I64
    cols: I64
    dist: F64
    dense: npt.NDArray[np.bool_]
    matrix: F64 | None = None

    @classmethod
    def empty(cls, dense: npt.NDArray[np.bool_], matrix: F64 | None = None) -> PairTable:
        none = np.zeros(0, dtype=np.int64)
        return cls(rows=none, cols=none.copy(), dist=np.zeros(0), dense=dense, matrix=matrix)
