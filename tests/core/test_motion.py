"""The vectorised Kalman filter agrees with filterpy's, step for step."""

from __future__ import annotations

import numpy as np
import pytest
from filterpy.kalman import KalmanFilter as FilterpyKF

from simpletrack.core.config import KalmanConfig
from simpletrack.core.motion import ConstantVelocity, KalmanFilter, align_yaw, transition


def _filterpy(z0: np.ndarray, kf: KalmanFilter) -> FilterpyKF:
    f = FilterpyKF(dim_x=10, dim_z=7)
    f.x = np.r_[z0, 0.0, 0.0, 0.0].reshape(10, 1)
    f.P = kf.p0.copy()
    f.Q = kf.q.copy()
    f.R = kf.r.copy()
    f.H = np.eye(7, 10)
    return f


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_kalman_matches_filterpy_over_irregular_steps(seed: int) -> None:
    rng = np.random.default_rng(seed)
    kf = KalmanFilter(KalmanConfig())
    n = 8
    z0 = rng.normal(size=(n, 7)) * 5
    z0[:, 3] = rng.uniform(-1.0, 1.0, n)  # headings within 90 degrees: no flip involved
    z0[:, 4:] = np.abs(z0[:, 4:]) + 0.5
    x, p = kf.initiate(z0)
    ref = [_filterpy(z0[i], kf) for i in range(n)]
    for _ in range(12):
        dt = rng.uniform(0.05, 1.0, n)
        z = x[:, :7] + rng.normal(scale=0.3, size=(n, 7))
        z[:, 3] = np.clip(z[:, 3], -1.4, 1.4)
        xp, pp = kf.predict(x, p, dt)
        x, p = kf.update(xp, pp, z)
        for i, f in enumerate(ref):
            f.F = transition(dt[i : i + 1])[0]
            f.predict()
            f.update(z[i].reshape(7, 1))
            np.testing.assert_allclose(xp[i], f.x_prior.ravel(), rtol=0, atol=1e-9)
            np.testing.assert_allclose(x[i], f.x.ravel(), rtol=0, atol=1e-9)
            np.testing.assert_allclose(p[i], f.P, rtol=0, atol=1e-9)


def test_prediction_moves_by_velocity_times_dt() -> None:
    kf = KalmanFilter(KalmanConfig())
    x, p = kf.initiate(np.array([[0.0, 0, 0, 0, 4, 2, 1.5]]))
    x[0, 7:10] = [2.0, -1.0, 0.0]
    xp, pp = kf.predict(x, p, np.array([0.5]))
    np.testing.assert_allclose(xp[0, :3], [1.0, -0.5, 0.0])
    assert pp[0, 0, 0] == pytest.approx(10 + 0.25 * 10000 + 1)


def test_yaw_correction_turns_opposite_heading() -> None:
    # A detection facing the other way: the prediction is turned by pi, not dragged around.
    out = align_yaw(np.array([0.1]), np.array([-3.0]))
    assert abs(out[0] - (-3.0)) < np.pi / 2
    # Nearly 2 pi apart across the wrap: brought together by 2 pi.
    out = align_yaw(np.array([-3.1]), np.array([3.1]))
    assert abs(out[0] - 3.1) < 0.1


def test_update_keeps_yaw_wrapped_and_close_to_detection() -> None:
    kf = KalmanFilter(KalmanConfig())
    x, p = kf.initiate(np.array([[0.0, 0, 0, 3.1, 4, 2, 1.5]]))
    xp, pp = kf.predict(x, p, np.array([0.1]))
    x2, _ = kf.update(xp, pp, np.array([[0.0, 0, 0, -3.1, 4, 2, 1.5]]))
    assert -np.pi <= x2[0, 3] < np.pi
    assert min(abs(x2[0, 3] - 3.1), abs(x2[0, 3] + 3.1)) < 0.1


def test_constant_velocity_uses_detector_velocity() -> None:
    cv = ConstantVelocity()
    x = cv.initiate(np.array([[1.0, 2, 0, 0, 4, 2, 1.5]]), np.array([[10.0, 0.0]]))
    np.testing.assert_allclose(cv.predict(x, np.array([0.1]))[0, :3], [2.0, 2.0, 0.0])
