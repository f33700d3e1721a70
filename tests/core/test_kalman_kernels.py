"""The compiled Kalman steps (core/kalman_kernels.py) against the textbook dense formulas
(numpy, the code they replaced) on random covariances and every yaw case, and against their
own uncompiled Python functions (SIMPLETRACK_JIT=0 runs those)."""

from __future__ import annotations

import numpy as np
import numpy.typing as npt
import pytest

from simpletrack.core import kalman_kernels as kk
from simpletrack.core.config import KalmanConfig
from simpletrack.core.motion import KalmanFilter, _wrap_once, align_yaw, transition

F64 = npt.NDArray[np.float64]
H = np.eye(7, 10)


def dense_predict(x: F64, p: F64, dt: F64, q: F64) -> tuple[F64, F64]:
    f = transition(dt)
    return np.einsum("tij,tj->ti", f, x), f @ p @ f.transpose(0, 2, 1) + q


def dense_update(x: F64, p: F64, z: F64, r: F64) -> tuple[F64, F64]:
    x, z = x.copy(), z.copy()
    x[:, 3] = align_yaw(x[:, 3], z[:, 3])
    z[:, 3] = _wrap_once(z[:, 3])
    s = p[:, :7, :7] + r
    k = p[:, :, :7] @ np.linalg.inv(s)
    x = x + np.einsum("tij,tj->ti", k, z - x[:, :7])
    a = np.eye(10) - k @ H
    p = a @ p @ a.transpose(0, 2, 1) + k @ r @ k.transpose(0, 2, 1)
    x[:, 3] = _wrap_once(x[:, 3])
    return x, p


def random_tracks(n: int, seed: int) -> tuple[F64, F64, F64, F64]:
    rng = np.random.default_rng(seed)
    x = rng.normal(size=(n, 10)) * 3
    x[:, 3] = rng.uniform(-3 * np.pi + 0.01, 3 * np.pi - 0.01, n)  # _wrap_once's domain
    m = rng.normal(size=(n, 10, 10))
    p = m @ m.transpose(0, 2, 1) + np.eye(10)  # symmetric positive definite
    z = x[:, :7] + rng.normal(scale=0.5, size=(n, 7))
    z[:, 3] = rng.uniform(-3 * np.pi + 0.01, 3 * np.pi - 0.01, n)  # every flip case
    return x, p, z, rng.uniform(0.0, 1.5, n)


@pytest.mark.parametrize("seed", range(4))
def test_predict_is_the_dense_product_to_rounding(seed: int) -> None:
    kf = KalmanFilter(KalmanConfig())
    x, p, _, dt = random_tracks(50, seed)
    xp, pp = kf.predict(x, p, dt)
    want_x, want_p = dense_predict(x, p, dt, kf.q)
    np.testing.assert_allclose(xp, want_x, rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(pp, want_p, rtol=1e-12, atol=1e-10)


@pytest.mark.parametrize("seed", range(4))
def test_update_is_the_dense_joseph_form_to_rounding(seed: int) -> None:
    kf = KalmanFilter(KalmanConfig(r=0.5))
    x, p, z, _ = random_tracks(50, seed)
    xu, pu = kf.update(x, p, z)
    want_x, want_p = dense_update(x, p, z, kf.r)
    np.testing.assert_allclose(xu, want_x, rtol=0, atol=1e-10)
    np.testing.assert_allclose(pu, want_p, rtol=1e-10, atol=1e-10)
    np.testing.assert_array_equal(pu, pu.transpose(0, 2, 1))  # published: exactly symmetric


def test_compiled_steps_equal_their_python_functions() -> None:
    kf = KalmanFilter(KalmanConfig())
    x, p, z, dt = random_tracks(20, 9)
    for fn, args in ((kk.predict_all, (x, p, dt, kf.q)), (kk.update_all, (x, p, z, kf.r))):
        compiled, plain = fn(*args), fn.py(*args)
        for c, q in zip(compiled, plain, strict=True):
            np.testing.assert_allclose(c, q, rtol=1e-13, atol=1e-13)


def test_no_tracks_is_no_work() -> None:
    kf = KalmanFilter(KalmanConfig())
    xp, pp = kf.predict(np.zeros((0, 10)), np.zeros((0, 10, 10)), np.zeros(0))
    xu, pu = kf.update(xp, pp, np.zeros((0, 7)))
    assert xp.shape == (0, 10) and pp.shape == (0, 10, 10)
    assert xu.shape == (0, 10) and pu.shape == (0, 10, 10)
