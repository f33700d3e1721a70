"""ImmortalTracker's life cycle (``revive_frames``) and its likelihood gate (``revive_gate``,
core/revive_kernels.py): a lost track keeps its id through an occlusion, is never reported
while lost, and an old prediction does not take a new object's detection."""

from __future__ import annotations

import math

import numpy as np
import pytest

from simpletrack.core.boxes import Boxes
from simpletrack.core.config import ClassConfig, KalmanConfig, OutputPolicy, TrackerConfig
from simpletrack.core.frames import Frame
from simpletrack.core.lifecycle import TrackState
from simpletrack.core.tracker import Tracker

SEEN = 30  # frames seen before the occlusion (10 Hz)
HIDDEN = 30  # 3 s unseen


def _tracker(output: OutputPolicy = OutputPolicy.REFERENCE, **cls: object) -> Tracker:
    c = ClassConfig.model_validate({"score_high": 0.5, "min_hits": 3, "max_age": 2, **cls})
    # A filter that believes a car keeps its speed (q 0.01 per frame): after 3 s of coasting
    # it still knows where the car is to a couple of metres. AB3DMOT's q = 1 spreads it over
    # ~15 m (docs/MOTION.md).
    return Tracker(TrackerConfig(classes={"car": c}, kalman=KalmanConfig(q=0.01), output=output))


def _frame(f: int, xs: list[float], score: float = 0.9) -> Frame:
    params = np.array([[x, 0.0, 0.0, 0.0, 4.0, 2.0, 1.5] for x in xs]).reshape(-1, 7)
    n = len(xs)
    return Frame(
        stamp=0.1 * f,
        boxes=Boxes(params=params, score=np.full(n, score), cls=np.zeros(n, dtype=np.int32)),
    )


def _run(tracker: Tracker, offset: float, hidden: int = HIDDEN) -> list[list[int]]:
    """A car at 5 m/s along x, unseen for ``hidden`` frames, then a car ``offset`` metres
    ahead of where it would be: the ids reported on each frame."""
    out = []
    for f in range(SEEN + hidden + 5):
        if SEEN <= f < SEEN + hidden:
            xs: list[float] = []
        else:
            xs = [5.0 * 0.1 * f + (offset if f >= SEEN else 0.0)]
        out.append(tracker.step(_frame(f, xs)).ids.tolist())
    return out


def _claim(tracker: Tracker, at: float, offset: float) -> float:
    """-2 ln of the lost track's likelihood for a detection ``offset`` m from its prediction
    at ``at`` seconds: d^2 + ln det(2 pi S)."""
    _, p = tracker._predict(tracker.tracks, at)
    s = p[0, :2, :2] + tracker._kf.r[:2, :2]
    d = np.array([offset, 0.0])
    return float(d @ np.linalg.solve(s, d) + math.log(np.linalg.det(2 * math.pi * s)))


def test_a_lost_track_comes_back_with_its_id_after_three_seconds() -> None:
    kept = _run(_tracker(revive_frames=40), 0.0)
    assert kept[SEEN + HIDDEN] == [0] and kept[-1] == [0]
    # Without it the car is somebody new after its two frames of grace.
    plain = _run(_tracker(), 0.0)
    assert plain[SEEN + HIDDEN] == [1]


@pytest.mark.parametrize("output", list(OutputPolicy))
def test_a_lost_track_is_never_reported(output: OutputPolicy) -> None:
    seen = _run(_tracker(output, revive_frames=40), 0.0)
    hidden = seen[SEEN + 2 : SEEN + HIDDEN]  # past max_age: lost, whatever the policy
    assert hidden == [[]] * len(hidden)


def test_a_lost_track_dies_after_its_revive_frames() -> None:
    tracker = _tracker(revive_frames=10)
    for f in range(SEEN + 2 + 9):
        tracker.step(_frame(f, [0.5 * f] if f < SEEN else []))
    assert tracker.tracks.state.tolist() == [TrackState.CONFIRMED]
    tracker.step(_frame(SEEN + 11, []))
    assert len(tracker.tracks) == 0


def test_a_lost_track_is_not_extended_by_a_low_score_detection() -> None:
    tracker = _tracker(revive_frames=40)
    for f in range(SEEN + 5):
        tracker.step(_frame(f, [0.5 * f] if f < SEEN else []))
    lost_for = int(tracker.tracks.time_since_update[0])
    tracker.step(_frame(SEEN + 5, [0.5 * (SEEN + 5)], score=0.3))  # stage 2 would take it
    assert int(tracker.tracks.time_since_update[0]) == lost_for + 1


def test_the_gate_keeps_an_old_prediction_off_a_new_object() -> None:
    probe = _tracker(revive_frames=40)
    _run_until_hidden(probe)
    at = 0.1 * (SEEN + HIDDEN)
    gate = _claim(probe, at, 1.0)  # claims a 1 m radius after 3 s
    assert _claim(probe, at, 2.0) > gate > _claim(probe, at, 0.5)

    assert _run(_tracker(revive_frames=40, revive_gate=gate), 0.5)[-1] == [0]
    taken = _run(_tracker(revive_frames=40, revive_gate=gate), 2.0)
    assert taken[SEEN + HIDDEN] == [1]  # a new object, a new id
    # Without the gate the lost track takes it: 2 m is well inside 1 - GIoU <= 1.5.
    assert _run(_tracker(revive_frames=40), 2.0)[SEEN + HIDDEN] == [0]
    # The longer lost, the less it claims: after 8 s its prediction is spread so wide that
    # even the car itself, back exactly where predicted, is a new object to it.
    late = 0.1 * (SEEN + 80)
    assert _claim(probe, late, 0.0) > gate
    assert _run(_tracker(revive_frames=100, revive_gate=gate), 0.0, hidden=80)[-1] == [1]


def _run_until_hidden(tracker: Tracker) -> None:
    for f in range(SEEN):
        tracker.step(_frame(f, [0.5 * f]))


@pytest.mark.parametrize("n", [2, 300])
def test_large_frames_gate_lost_tracks_as_ordinary_ones_do(n: int) -> None:
    # 300 cars a frame against 300 tracks is past the dense table (gated pairs,
    # core/pairs.py) and the compiled step; 2 is an ordinary frame. Every other car hides
    # for a second and comes back 1 m off: kept by an open gate, new under a shut one
    # (0: no likelihood beats a density of 1 per m^2 here).
    def kept(gate: float | None) -> float:
        tracker = _tracker(revive_frames=20, revive_gate=gate)
        odd = np.arange(n) % 2 == 1
        first: dict[float, int] = {}
        last: dict[float, int] = {}
        for f in range(40):
            params = np.zeros((n, 7))
            params[:, 0] = 0.5 * f + np.where(odd & (f >= 30), 1.0, 0.0)
            params[:, 1] = np.arange(n) * 10.0
            params[:, 4:] = (4.0, 2.0, 1.5)
            params = params[~odd | (f < 20) | (f >= 30)]
            frame = Frame(
                stamp=0.1 * f,
                boxes=Boxes(
                    params=params,
                    score=np.full(len(params), 0.9),
                    cls=np.zeros(len(params), np.int32),
                ),
            )
            out = tracker.step(frame)
            for y, i in zip(out.boxes.params[:, 1].tolist(), out.ids.tolist(), strict=True):
                first.setdefault(y, i)
                last[y] = i
        return float(np.mean([first[y] == last[y] for y in last if int(y / 10) % 2 == 1]))

    assert kept(None) == 1.0
    assert kept(0.0) == 0.0
