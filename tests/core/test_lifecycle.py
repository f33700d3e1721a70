"""Life-cycle tables: how hits and misses move a track between states, frame by frame."""

from __future__ import annotations

import pytest

from simpletrack.core.config import Matcher, Metric, MotionModel, OutputPolicy
from simpletrack.core.lifecycle import TrackState
from simpletrack.core.tracker import Tracker
from tests.core.helpers import car, config, frame

T, C = TrackState.TENTATIVE, TrackState.CONFIRMED
GONE = None  # removed (dead)


def _states(pattern: str, min_hits: int, max_age: int, warmup: int) -> list[TrackState | None]:
    """Feed one object seen ('x') or missed ('.') after ``warmup`` empty frames; return the
    track's state after each frame of the pattern."""
    t = Tracker(config(min_hits=min_hits, max_age=max_age, two_stage=False))
    for k in range(warmup):
        t.step(frame([], 0.1 * k))
    out: list[TrackState | None] = []
    for i, ch in enumerate(pattern):
        k = warmup + i
        t.step(frame([car(0.3 * k)] if ch == "x" else [], 0.1 * k))
        live = t.tracks.state[t.tracks.ids == 0].tolist()
        out.append(TrackState(live[0]) if live else GONE)
    return out


@pytest.mark.parametrize(
    ("pattern", "min_hits", "max_age", "warmup", "expected"),
    [
        # Late in a sequence: tentative until min_hits hits, then confirmed.
        ("xxxx", 3, 2, 5, [T, T, C, C]),
        # A tentative track missed max_age times in a row dies.
        ("x..", 3, 2, 5, [T, T, GONE]),
        # A confirmed track survives max_age - 1 misses, then dies.
        ("xxx.x", 3, 2, 5, [T, T, C, C, C]),
        ("xxx..", 3, 2, 5, [T, T, C, C, GONE]),
        ("xxx...", 3, 4, 5, [T, T, C, C, C, C]),
        # In the first min_hits frames of a sequence a track is confirmed at birth.
        ("xx", 3, 2, 0, [C, C]),
        # min_hits 0 confirms at once; misses still kill it.
        ("x.", 0, 1, 5, [C, GONE]),
    ],
)
def test_life_cycle_table(
    pattern: str, min_hits: int, max_age: int, warmup: int, expected: list[TrackState | None]
) -> None:
    assert _states(pattern, min_hits, max_age, warmup) == expected


@pytest.mark.parametrize(
    ("metric", "matcher", "max_distance"),
    [
        (Metric.GIOU_3D, Matcher.GREEDY, 1.5),
        (Metric.IOU_3D, Matcher.HUNGARIAN, 0.9),
        (Metric.GIOU_BEV, Matcher.HUNGARIAN, 1.5),
        (Metric.L2, Matcher.GREEDY, 2.0),
        (Metric.MAHALANOBIS, Matcher.GREEDY, 10.0),
    ],
)
def test_every_metric_and_matcher_keeps_two_crossing_objects_apart(
    metric: Metric, matcher: Matcher, max_distance: float
) -> None:
    t = Tracker(
        config(
            min_hits=1,
            metric=metric.value,
            matcher=matcher.value,
            max_distance=max_distance,
            stage2_max_distance=max_distance,
        )
    )
    for k in range(10):
        a, b = car(0.4 * k, 0.0), car(0.4 * k, 5.0)
        t.step(frame([a, b], 0.1 * k))
    by_y = {round(float(y)): int(i) for y, i in zip(t.tracks.x[:, 1], t.tracks.ids, strict=True)}
    assert by_y == {0: 0, 5: 1}


def test_constant_velocity_model_uses_the_detector_velocity() -> None:
    import numpy as np

    from simpletrack.core.boxes import Boxes
    from simpletrack.core.frames import Frame

    cfg = config(min_hits=1, output=OutputPolicy.NUSCENES).with_overrides(
        motion=MotionModel.CONSTANT_VELOCITY
    )
    t = Tracker(cfg)
    box = np.array([[0.0, 0.0, 0.0, 0.0, 4.0, 2.0, 1.5]])
    vel = np.array([[10.0, 0.0]])
    t.step(Frame(Boxes.from_arrays(box, [0.9], [0], vel), 0.0))
    out = t.step(Frame(Boxes.empty(with_velocity=True), 0.5))
    assert out.boxes.x.tolist() == pytest.approx([5.0])  # coasting on 10 m/s for 0.5 s
