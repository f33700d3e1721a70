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


_BASE = {"score_high": 0.5, "score_low": 0.1, "min_hits": 3, "max_age": 2, "nms_iou": 0.25}


def config(output: OutputPolicy = OutputPolicy.PAPER, **cls: object) -> TrackerConfig:
    c = ClassConfig.model_validate({**_BASE, **cls})
    return TrackerConfig(classes={"car": c, "pedestrian": c}, output=output)


def models_config(
    output: OutputPolicy = OutputPolicy.PAPER, pedestrian: str = "bicycle"
) -> TrackerConfig:
    """Cars by CTRA with a gated ImmortalTracker life, pedestrians by ``pedestrian`` (cv:
    constant-velocity rows in a 12-d table) with an ungated one: the motion models, lost
    tracks and their gate on every path."""
    car = {"motion_model": "ctra", "max_age": 3, "revive_frames": 6, "revive_gate": 9.0}
    ped = {"motion_model": pedestrian, "revive_frames": 4}
    return TrackerConfig(
        classes={
            "car": ClassConfig.model_validate({**_BASE, **car}),
            "pedestrian": ClassConfig.model_validate({**_BASE, **ped}),
        },
        output=output,
    )


def crowd(
    seed: int,
    frames: int,
    n: int,
    *,
    seen: float,
    with_velocity: bool = False,
    non_key_every: int = 0,
) -> list[Frame]:
    """Two classes of ``n`` boxes that come (each frame with probability ``seen``), go, jitter
    and cross at 10 Hz: matches, misses, births and ties. ``with_velocity`` gives the boxes
    their true velocity; ``non_key_every`` > 0 makes every such frame (counted from 1) non-key."""
    rng = np.random.default_rng(seed)
    base = rng.uniform(-15, 15, (n, 2))
    vel = rng.normal(scale=1.0, size=(n, 2))
    cls = rng.integers(0, 2, n).astype(np.int32)
    out = []
    for k in range(frames):
        here = rng.random(n) < seen
        p = np.zeros((int(here.sum()), 7))
        p[:, :2] = base[here] + vel[here] * k * 0.1 + rng.normal(scale=0.3, size=(p.shape[0], 2))
        p[:, 3] = rng.normal(scale=0.1, size=p.shape[0])
        p[:, 4:7] = [4.0, 2.0, 1.5]
        score = np.round(rng.uniform(0.05, 1.0, p.shape[0]), 1)
        boxes = Boxes.from_arrays(p, score, cls[here], vel[here] if with_velocity else None)
        key = non_key_every == 0 or (k + 1) % non_key_every != 0
        out.append(Frame(boxes=boxes, stamp=k * 0.1, key_frame=key))
    return out
