"""The motion models of config.MotionKind (core/motion_kernels.py) against hand-computed
predictions, and their place in a tracker: each class by its own model, the paper's
constant velocity unchanged."""

from __future__ import annotations

import math

import numpy as np
import pytest

from simpletrack.core.boxes import Boxes
from simpletrack.core.config import ClassConfig, MotionKind, TrackerConfig
from simpletrack.core.frames import Frame
from simpletrack.core.kalman_kernels import predict_all
from simpletrack.core.motion import MODEL_CODES, MODEL_Q
from simpletrack.core.motion_kernels import predict_models
from simpletrack.core.tracker import Tracker
from tests.core.helpers import models_config

KINDS = (MotionKind.CV, MotionKind.CA, MotionKind.CTRA, MotionKind.BICYCLE)
MODEL = np.array([MODEL_CODES[k] for k in KINDS], dtype=np.int64)
Q = np.zeros((len(KINDS), 12))


def _predict(state: list[float], kind: MotionKind, dt: float, p: np.ndarray | None = None):
    x = np.array([state], dtype=np.float64)
    cov = np.eye(12)[None] if p is None else p[None]
    cls = np.array([KINDS.index(kind)], dtype=np.int32)
    got = predict_models(x, cov, np.array([dt]), cls, MODEL, Q)
    plain = predict_models.py(x, cov, np.array([dt]), cls, MODEL, Q)
    np.testing.assert_allclose(got[0], plain[0], rtol=0, atol=1e-12)
    np.testing.assert_allclose(got[1], plain[1], rtol=0, atol=1e-9)
    return got[0][0], got[1][0]


def _state(x: float, y: float, yaw: float, vx: float, vy: float, e0: float, e1: float):
    return [x, y, 0.5, yaw, 4.5, 1.8, 1.6, vx, vy, 0.0, e0, e1]


@pytest.mark.parametrize("kind", [MotionKind.CTRA, MotionKind.BICYCLE])
@pytest.mark.parametrize("dt", [0.1, 0.5, 2.0])
def test_a_car_on_a_circle_stays_on_it(kind: MotionKind, dt: float) -> None:
    # Radius 20 m at 10 m/s, counter-clockwise around the origin, starting at (20, 0)
    # heading +y: after dt it is at the angle w dt on the circle, heading turned by w dt.
    radius, speed = 20.0, 10.0
    w = speed / radius
    e0 = w if kind is MotionKind.CTRA else 1.0 / radius  # turn rate, or curvature
    x, _ = _predict(_state(radius, 0.0, math.pi / 2, 0.0, speed, e0, 0.0), kind, dt)
    angle = w * dt
    assert x[0] == pytest.approx(radius * math.cos(angle), abs=1e-9)
    assert x[1] == pytest.approx(radius * math.sin(angle), abs=1e-9)
    assert x[7] == pytest.approx(-speed * math.sin(angle), abs=1e-9)
    assert x[8] == pytest.approx(speed * math.cos(angle), abs=1e-9)
    assert x[3] == pytest.approx(math.pi / 2 + angle, abs=1e-12)
    assert (x[10], x[11]) == (e0, 0.0)


@pytest.mark.parametrize("kind", [MotionKind.CTRA, MotionKind.BICYCLE])
def test_a_cyclist_braking_stops_where_the_brakes_say(kind: MotionKind) -> None:
    # 5 m/s along x, braking at 2 m/s^2: after 1 s, 5 - 1 = 4 m on at 3 m/s; the stop comes
    # at 2.5 s after 6.25 m, and a longer step stays there at rest.
    start = _state(0.0, 0.0, 0.0, 5.0, 0.0, 0.0, -2.0)
    x, _ = _predict(start, kind, 1.0)
    assert (x[0], x[1], x[7], x[8]) == pytest.approx((4.0, 0.0, 3.0, 0.0), abs=1e-12)
    x, _ = _predict(start, kind, 3.0)
    assert (x[0], x[7]) == pytest.approx((6.25, 0.0), abs=1e-12)


def test_constant_acceleration_is_the_school_formula() -> None:
    x, p = _predict(_state(1.0, 2.0, 0.3, 3.0, -1.0, 0.5, 2.0), MotionKind.CA, 2.0)
    assert x[0] == pytest.approx(1.0 + 3.0 * 2 + 0.5 * 0.5 * 4, abs=1e-12)
    assert x[1] == pytest.approx(2.0 - 1.0 * 2 + 0.5 * 2.0 * 4, abs=1e-12)
    assert (x[7], x[8], x[3]) == pytest.approx((3.0 + 1.0, -1.0 + 4.0, 0.3), abs=1e-12)
    # Linear: the Jacobian is F exactly, so P = F F^T here (P was I, Q zero).
    f = np.eye(12)
    for i, v, a in ((0, 7, 10), (1, 8, 11)):
        f[i, v], f[i, a], f[v, a] = 2.0, 2.0, 2.0
    f[2, 9] = 2.0
    np.testing.assert_allclose(p, f @ f.T, atol=1e-6)


def test_the_turn_rate_covariance_follows_the_jacobian() -> None:
    # An EKF step: the position's spread across the track gains the turn rate's variance
    # times (d position / d turn rate)^2 = (v dt^2 / 2)^2 for a small turn.
    p = np.zeros((12, 12))
    p[10, 10] = 0.04
    _, cov = _predict(_state(0, 0, 0, 10.0, 0.0, 0.0, 0.0), MotionKind.CTRA, 1.0, p)
    assert cov[1, 1] == pytest.approx(0.04 * (10.0 * 1.0 / 2) ** 2, rel=1e-5)
    assert cov[0, 0] == pytest.approx(0.0, abs=1e-9)
    assert cov[3, 3] == pytest.approx(0.04, rel=1e-6)  # the yaw turns with the motion


def test_constant_velocity_rows_are_the_papers_filter_bit_for_bit() -> None:
    rng = np.random.default_rng(3)
    x = rng.normal(size=(6, 12))
    a = rng.normal(size=(6, 12, 12))
    p = a @ a.transpose(0, 2, 1)
    p[:, 10:, :10] = p[:, :10, 10:] = 0.0  # a cv row never couples its extra states
    dt = rng.uniform(0.05, 1.0, 6)
    cls = np.zeros(6, dtype=np.int32)
    q = np.full((4, 12), 1.0)
    got_x, got_p = predict_models(x, p, dt, cls, MODEL, q)
    ref_x, ref_p = predict_all(
        np.ascontiguousarray(x[:, :10]), np.ascontiguousarray(p[:, :10, :10]), dt, np.eye(10)
    )
    np.testing.assert_array_equal(got_x[:, :10], ref_x)
    np.testing.assert_array_equal(got_p[:, :10, :10], ref_p)


def _circle_track(kind: MotionKind, gap: range) -> tuple[float, list[int]]:
    """A car on a 15 m circle at 6 m/s (10 Hz), unseen during ``gap``: the error of the
    first prediction after the gap, and the ids reported over the run."""
    c = ClassConfig(score_high=0.5, min_hits=1, max_age=2 + len(gap), motion_model=kind)
    tracker = Tracker(TrackerConfig(classes={"car": c}))
    radius, speed = 15.0, 6.0
    error, ids = math.nan, []
    for f in range(gap.stop + 1):
        a = speed / radius * f * 0.1
        here = np.array(
            [[radius * math.cos(a), radius * math.sin(a), 0, a + math.pi / 2, 4, 2, 1.5]]
        )
        if f == gap.stop:
            x, _ = tracker._predict(tracker.tracks, f * 0.1)
            error = float(np.hypot(*(x[0, :2] - here[0, :2])))
        boxes = here[:0] if f in gap else here
        out = tracker.step(
            Frame(
                stamp=f * 0.1,
                boxes=Boxes(
                    params=boxes, score=np.full(len(boxes), 0.9), cls=np.zeros(len(boxes), np.int32)
                ),
            )
        )
        ids += out.ids.tolist()
    return error, ids


def test_a_turning_car_is_predicted_through_an_occlusion_better_by_a_turn_model() -> None:
    gap = range(40, 55)  # 1.5 s unseen, a 34 degree turn
    errors = {kind: _circle_track(kind, gap) for kind in KINDS}
    cv, cv_ids = errors[MotionKind.CV]
    assert cv > 5.0 and set(cv_ids) == {0, 1}  # off the circle: the car comes back as new
    for kind in (MotionKind.CTRA, MotionKind.BICYCLE):
        error, ids = errors[kind]
        assert error < cv / 3 and set(ids) == {0}, (kind, error, cv)


def test_model_noise_defaults_are_written_down() -> None:
    assert set(MODEL_Q) == set(KINDS) - {MotionKind.CV}
    with pytest.raises(ValueError, match="model_noise needs a motion_model other than cv"):
        ClassConfig(model_noise=(0.1, 0.1))
    with pytest.raises(ValueError, match="needs motion kalman"):
        TrackerConfig(classes={"car": ClassConfig(motion_model="ctra")}, motion="constant_velocity")
    with pytest.raises(ValueError, match=r"process_noise \(0.1, 1.0\) needs motion kalman"):
        TrackerConfig(
            classes={"car": ClassConfig(process_noise=(0.1, 1.0))}, motion="constant_velocity"
        )


def test_a_tracker_with_models_restores_its_twelve_states() -> None:
    tracker = Tracker(models_config())
    assert tracker.tracks.x.shape == (0, 12)
    boxes = np.array([[1.0, 2, 0, 0, 4, 2, 1.5], [5, 5, 0, 1, 0.6, 0.6, 1.7]])
    for f in range(4):
        b = boxes + np.array([0.5 * f, 0, 0, 0, 0, 0, 0])
        tracker.step(
            Frame(
                stamp=0.1 * f,
                boxes=Boxes(params=b, score=np.full(2, 0.9), cls=np.array([0, 1], np.int32)),
            )
        )
    again = Tracker.from_bytes(tracker.to_bytes())
    assert again.tracks.x.shape == (2, 12)
    np.testing.assert_array_equal(again.tracks.p, tracker.tracks.p)
    assert Tracker(TrackerConfig(classes={"car": ClassConfig()})).tracks.x.shape == (0, 10)


def test_a_class_process_noise_of_ones_is_the_papers_filter_and_a_smaller_one_trusts_motion() -> (
    None
):
    from tests.core.helpers import config, crowd

    frames = crowd(4, 30, 30, seen=0.8)
    plain = Tracker(config())
    same = Tracker(config(process_noise=(1.0, 1.0)))
    assert same._models and same.tracks.x.shape[1] == 10
    for f in frames:
        a, b = plain.step(f), same.step(f)
        np.testing.assert_array_equal(a.ids, b.ids)
        np.testing.assert_array_equal(a.boxes.params, b.boxes.params)
        np.testing.assert_array_equal(a.covariance, b.covariance)
    calm = Tracker(config(process_noise=(0.01, 0.01)))
    for f in frames:
        out = calm.step(f)
    assert out.covariance is not None and len(out)
    assert float(np.median(out.covariance[:, 0, 0])) < float(np.median(a.covariance[:, 0, 0])) / 2
