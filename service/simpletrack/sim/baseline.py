"""The demo's baseline: the raw detections scored as if they were the tracker's output.

What a planner without a tracker would use: each class's boxes scoring at least its
``score_high`` (the tracker's stage-1 threshold), after the same class-aware NMS the tracker
runs, moved to the world frame with the frame's pose. Detections carry no identity: the
baseline gets a fresh id per box per frame, so its IDS would count every re-detection of an
object as a switch (a figure about having no ids, not about detection). Its MOTA is therefore
reported without the IDS term, 1 - (FN + FP) / GT: the best the detections alone could
score, which makes "the tracker beats the detections" a claim about what tracking adds.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import numpy.typing as npt

from simpletrack.core.boxes import Boxes, transform_boxes
from simpletrack.core.config import TrackerConfig
from simpletrack.core.nms import nms
from simpletrack.eval.clear_mot import MotCounts


def detections_alone(
    detections: Boxes, pose: npt.NDArray[np.float64], config: TrackerConfig
) -> Boxes:
    """``detections`` (sensor frame) as a planner without a tracker would keep them, in the
    world frame."""
    codes = range(len(config.class_names))
    score_high = np.array([config.for_code(c).score_high for c in codes])
    nms_iou = np.array([config.for_code(c).nms_iou for c in codes])
    kept = detections.take(np.flatnonzero(detections.score >= score_high[detections.cls]))
    world = transform_boxes(kept, pose)
    return world.take(
        nms(world, nms_iou, vertical=config.vertical_overlap, tie_order=config.tie_order)
    )


def without_identity(counts: MotCounts) -> MotCounts:
    """The counts with the identity figures dropped (see the module docstring)."""
    return dataclasses.replace(counts, ids=0, objects=0, id_links=0)
