"""Detection pre-processing: drop degenerate boxes, then class-aware 3D-IoU NMS (spec: Pre-processing)."""

from __future__ import annotations

import numpy as np
import numpy.typing as npt

from simpletrack.core.boxes import Boxes
from simpletrack.core.config import TieOrder, VerticalOverlap
from simpletrack.core.geometry import iou_3d_pairs
from simpletrack.core.ordering import descending_reference, descending_stable

I64 = npt.NDArray[np.int64]


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
    codes = np.unique(cls)
    if codes[0] < 0 or codes[-1] >= thr.size:
        raise ValueError(
            f"class codes span {codes[0]}..{codes[-1]} but only {thr.size} NMS thresholds given"
        )
    # One sparse IoU pass over every same-class pair that can overlap, for all classes at once.
    rows, cols, iou = iou_3d_pairs(
        boxes.params, boxes.params, vertical=vertical, groups_a=cls, groups_b=cls
    )
    hit = (iou > thr[cls[rows]]) & (rows != cols)
    rows, cols = rows[hit], cols[hit]  # still row-major: each row's partners are contiguous
    start = np.searchsorted(rows, np.arange(len(boxes) + 1)).tolist()
    partners = cols.tolist()
    descending = descending_stable if tie_order is TieOrder.STABLE else descending_reference
    walk: list[I64] = []
    for code in codes:
        members = np.flatnonzero(cls == code)
        walk.append(members[descending(boxes.score[members])])
    order = np.concatenate(walk)
    # The greedy walk is over boxes, not pairs: a kept box suppresses its listed partners.
    suppressed = bytearray(len(boxes))
    kept: list[int] = []
    for i in order.tolist():
        if not suppressed[i]:
            kept.append(i)
            for j in partners[start[i] : start[i + 1]]:
                suppressed[j] = 1
    return np.asarray(kept, dtype=np.int64)
