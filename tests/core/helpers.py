"""Small builders for core scenario tests."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from simpletrack.core.boxes import Boxes
from simpletrack.core.config import ClassConfig, OutputPolicy, TrackerConfig
from simpletrack.core.frames import Frame


def car(
    x: float, y: float = 0.0, score: float = 0.9, cls: int = 0, yaw: float = 0.0
) -> list[float]:
    return [x, y, 0.0, yaw, 4.0, 2.0, 1.5, score, cls]


def frame(rows: Sequence[Sequence[float]], stamp: float, key_frame: bool = True) -> Frame:
    a = np.array(rows, dtype=np.float64).reshape(-1, 9)
    boxes = Boxes.from_arrays(a[:, :7], a[:, 7], a[:, 8].astype(np.int32))
    return Frame(boxes=boxes, stamp=stamp, key_frame=key_frame)


def config(output: OutputPolicy = OutputPolicy.PAPER, **cls: object) -> TrackerConfig:
    base = {"score_high": 0.5, "score_low": 0.1, "min_hits": 3, "max_age": 2, "nms_iou": 0.25}
    base.update(cls)
    c = ClassConfig.model_validate(base)
    return TrackerConfig(classes={"car": c, "pedestrian": c}, output=output)
