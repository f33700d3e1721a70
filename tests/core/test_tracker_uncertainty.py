"""What a planner reads besides the box: each track's covariance (the Kalman filter's
estimate over x, y, z, vx, vy, vz) and its age and time since update in seconds."""

from __future__ import annotations

from dataclasses import replace

import msgpack
import numpy as np
import pytest

from simpletrack.core.config import MotionModel
from simpletrack.core.frames import POS_VEL
from simpletrack.core.motion import KalmanFilter
from simpletrack.core.tracker import Tracker
from tests.core.helpers import car, config, frame

BLOCK = np.ix_(POS_VEL, POS_VEL)


def test_covariance_is_the_filters_block_after_an_update_and_while_coasting() -> None:
    cfg = config(min_hits=1, max_age=4, two_stage=False, coast_output=3)
    kf = KalmanFilter(cfg.kalman)
    t = Tracker(cfg)
    born = t.step(frame([car(0.0)], 0.0))
    x, p = kf.initiate(np.array([[0.0, 0.0, 0.0, 0.0, 4.0, 2.0, 1.5]]))
    assert born.covariance is not None
    np.testing.assert_allclose(born.covariance[0], p[0][BLOCK])

    updated = t.step(frame([car(0.5)], 0.1))
    x, p = kf.predict(x, p, np.array([0.1]))
    x, p = kf.update(x, p, np.array([[0.5, 0.0, 0.0, 0.0, 4.0, 2.0, 1.5]]))
    assert updated.covariance is not None
    np.testing.assert_allclose(updated.covariance[0], p[0][BLOCK], rtol=1e-12)

    coasting = t.step(frame([], 0.35))  # reported by coast_output: its predicted box
    _, p_pred = kf.predict(x, p, np.array([0.25]))
    assert coasting.covariance is not None and len(coasting) == 1
    np.testing.assert_allclose(coasting.covariance[0], p_pred[0][BLOCK], rtol=1e-12)
    # Uncertainty grows while nothing is measured, and the matrix stays symmetric.
    assert np.trace(coasting.covariance[0]) > np.trace(updated.covariance[0])
    np.testing.assert_array_equal(coasting.covariance[0], coasting.covariance[0].T)


def test_ages_in_seconds_count_from_birth_and_from_the_last_update() -> None:
    t = Tracker(config(min_hits=1, max_age=4, two_stage=False, coast_output=3))
    for k, stamp in enumerate((10.0, 10.1, 10.2)):
        out = t.step(frame([car(0.5 * k)], stamp))
    assert out.age_s is not None and out.time_since_update_s is not None
    assert out.age_s.tolist() == [pytest.approx(0.2)]
    assert out.time_since_update_s.tolist() == [0.0]
    t.step(frame([], 10.3))
    out = t.step(frame([], 10.45))
    assert out.age.tolist() == [4] and out.time_since_update.tolist() == [2]
    assert out.age_s is not None and out.time_since_update_s is not None
    assert out.age_s.tolist() == [pytest.approx(0.45)]
    assert out.time_since_update_s.tolist() == [pytest.approx(0.25)]


def test_constant_velocity_tracks_carry_no_covariance() -> None:
    cfg = config(min_hits=1).model_copy(update={"motion": MotionModel.CONSTANT_VELOCITY})
    t = Tracker(cfg)
    t.step(frame([car(0.0)], 0.0))
    out = t.step(frame([car(0.1)], 0.1))
    assert len(out) == 1 and out.covariance is None
    assert out.age_s is not None and out.age_s.tolist() == [pytest.approx(0.1)]


def test_covariance_in_the_sensor_frame_turns_with_the_pose() -> None:
    t = Tracker(config(min_hits=1))
    t.step(frame([car(0.0)], 0.0))
    out = t.step(frame([car(0.5)], 0.1))
    quarter = np.array([[0.0, -1.0, 0, 3.0], [1.0, 0.0, 0, -2.0], [0, 0, 1.0, 0], [0, 0, 0, 1.0]])
    assert out.covariance is not None
    cov = out.covariance.copy()
    cov[0, 0, 0] += 1.0  # make x and y distinguishable
    turned = replace(out, covariance=cov)
    sensor = turned.in_sensor_frame(quarter)
    assert sensor.covariance is not None
    assert sensor.covariance[0, 1, 1] == pytest.approx(cov[0, 0, 0])
    assert sensor.covariance[0, 0, 0] == pytest.approx(cov[0, 1, 1])


def test_a_snapshot_from_before_birth_stamps_restores_and_continues() -> None:
    cfg = config(min_hits=1, max_age=4, two_stage=False)
    frames = [[car(0.5 * k)] for k in range(8)]
    whole = Tracker(cfg)
    full = [whole.step(frame(rows, 0.1 * k)) for k, rows in enumerate(frames)]
    t = Tracker(cfg)
    for k, rows in enumerate(frames[:4]):
        t.step(frame(rows, 0.1 * k))
    old = msgpack.unpackb(t.to_bytes(), raw=False)
    del old["tracks"]["t_birth"]  # the key set snapshots had before the column
    restored = Tracker.from_bytes(msgpack.packb(old, use_bin_type=True))
    np.testing.assert_array_equal(restored.tracks.t_birth, restored.tracks.t_update)
    for k, rows in enumerate(frames[4:], start=4):
        out = restored.step(frame(rows, 0.1 * k))
        assert out.ids.tolist() == full[k].ids.tolist()
        np.testing.assert_array_equal(out.boxes.params, full[k].boxes.params)
        np.testing.assert_array_equal(out.covariance, full[k].covariance)  # type: ignore[arg-type]
    # The age in seconds restarts at the last update before the snapshot (0.3 s): a lower bound.
    assert out.age_s is not None and out.age_s.tolist() == [pytest.approx(0.7 - 0.3)]
    assert full[-1].age_s is not None and full[-1].age_s.tolist() == [pytest.approx(0.7)]
