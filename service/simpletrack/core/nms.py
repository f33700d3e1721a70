"""Detection pre-processing: drop degenerate boxes, then class-aware 3D-IoU NMS (spec: Pre-processing)."""

from __future__ import annotations

import numpy as np
import numpy.typing as npt

from simpletrack.core.boxes import F64, Boxes
from simpletrack.core.config import TieOrder, VerticalOverlap
from simpletrack.core.geometry import iou_3d_pairs
from simpletrack.core.ordering import descending_reference
from simpletrack.core.pair_kernels import nms_walk as walk_kernel

I64 = npt.NDArray[np.int64]
# Same-class pairs up to which the compiled walk tests every pair it needs (~1 ms at most);
# past it the BEV grid lists the few pairs that can overlap.
_WALK_PAIRS = 1 << 18
# Frames of at most this many boxes are walked whole whatever their classes (512^2 = 2^18).
NMS_WALK_BOXES = 512


def drop_degenerate(boxes: Boxes) -> I64:
    """Indices (ascending) of the boxes to KEEP: everything finite, and l, w, h all > 0."""
    keep = boxes.valid_mask()
    if boxes.velocity is not None:
        keep &= np.isfinite(boxes.velocity).all(axis=1)
    return np.flatnonzero(keep).astype(np.int64)


def nms(
    boxes: Boxes,
    iou_threshold: npt.ArrayLike,
    *,
    vertical: VerticalOverlap = VerticalOverlap.EXACT,
    tie_order: TieOrder = TieOrder.STABLE,
) -> I64:
    """Kept indices after per-class NMS: classes in ascending code, each in descending score.

    ``iou_threshold[c]`` is class c's threshold: a box is suppressed when its 3D IoU with an
    already kept box of its class is > the threshold (the reference keeps IoU <= threshold).
    Within a class, equal scores keep input order (``STABLE``) or the order the reference saw
    (``REFERENCE``: NumPy's classic introsort; see service/simpletrack/core/ordering.py).
    """
    thr = np.asarray(iou_threshold, dtype=np.float64).reshape(-1)
    if len(boxes) == 0:
        return np.zeros(0, dtype=np.int64)
    cls = boxes.cls
    lo, hi = int(cls.min()), int(cls.max())
    if lo < 0 or hi >= thr.size:
        raise ValueError(f"class codes span {lo}..{hi} but only {thr.size} NMS thresholds given")
    order = nms_order(boxes, tie_order)
    per_class = np.bincount(cls)
    exact = vertical is VerticalOverlap.EXACT
    if int(np.dot(per_class, per_class)) <= _WALK_PAIRS:
        return walk_kernel(boxes.params, cls.astype(np.int64), order, thr, exact)
    return _gated_walk(boxes, thr, order, vertical)


def nms_order(boxes: Boxes, tie_order: TieOrder) -> I64:
    """The walk's order: ascending class, each in descending score; equal scores in input
    order (``STABLE``) or as the reference's sort left them (``REFERENCE``)."""
    cls = boxes.cls
    if tie_order is TieOrder.STABLE:
        # What descending_stable gives class by class: lexsort is stable.
        return np.lexsort((-boxes.score, cls)).astype(np.int64)
    members = [np.flatnonzero(cls == c) for c in np.unique(cls)]
    return np.concatenate([m[descending_reference(boxes.score[m])] for m in members])


def _gated_walk(boxes: Boxes, thr: F64, order: I64, vertical: VerticalOverlap) -> I64:
    """The walk of large frames: one sparse IoU pass over the pairs the BEV grid cannot rule
    out (near-linear in the boxes), then the greedy walk over boxes in ``order``."""
    cls = boxes.cls
    rows, cols, iou = iou_3d_pairs(
        boxes.params, boxes.params, vertical=vertical, groups_a=cls, groups_b=cls
    )
    hit = (iou > thr[cls[rows]]) & (rows != cols)
    rows, cols = rows[hit], cols[hit]  # still row-major: each row's partners are contiguous
    start = np.searchsorted(rows, np.arange(len(boxes) + 1)).tolist()
    partners = cols.tolist()
    # The greedy walk is over boxes, not pairs: a kept box suppresses its listed partners.
    suppressed = bytearray(len(boxes))
    kept: list[int] = []
    for i in order.tolist():
        if not suppressed[i]:
            kept.append(i)
            for j in partners[start[i] : start[i + 1]]:
                suppressed[j] = 1
    return np.asarray(kept, dtype=np.int64)
