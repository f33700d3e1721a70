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


def dense_loops(x: F64, p: F64, z: F64, r: F64) -> tuple[F64, F64]:
    """The kernel's dense path as it was before the constant-velocity pattern got its own
    (plain Python, the same scalar operations in the same order): what that path must equal
    bit for bit."""
    n, nx = x.shape[0], x.shape[1]
    x_out, p_out = np.empty((n, nx)), np.empty((n, nx, nx))
    with np.errstate(all="ignore"):  # inf times a zero is the NaN compiled code gives silently
        _dense_loops_into(x, p, z, r, x_out, p_out)
    return x_out, p_out


def _dense_loops_into(x: F64, p: F64, z: F64, r: F64, x_out: F64, p_out: F64) -> None:
    n, nx, nz = x.shape[0], x.shape[1], 7
    for t in range(n):
        yaw = kk._align_yaw(x[t, 3], z[t, 3])
        y = [kk.wrap_once(z[t, i]) - yaw if i == 3 else z[t, i] - x[t, i] for i in range(nz)]
        aug = np.zeros((nz, 2 * nz))
        for i in range(nz):
            for j in range(nz):
                aug[i, j] = p[t, i, j] + r[i, j]
                aug[i, nz + j] = 1.0 if i == j else 0.0
        for c in range(nz):
            pivot, best = c, abs(aug[c, c])
            for i in range(c + 1, nz):
                if abs(aug[i, c]) > best:
                    pivot, best = i, abs(aug[i, c])
            if pivot != c:
                aug[[c, pivot]] = aug[[pivot, c]]
            inv = 1.0 / aug[c, c]
            for j in range(2 * nz):
                aug[c, j] *= inv
            for i in range(nz):
                f = aug[i, c]
                if i != c and f != 0.0:
                    for j in range(2 * nz):
                        aug[i, j] -= f * aug[c, j]
        k = np.empty((nx, nz))
        kr = np.empty((nx, nz))
        ap = np.empty((nx, nx))
        for i in range(nx):
            for j in range(nz):
                acc = 0.0
                for m in range(nz):
                    acc += p[t, i, m] * aug[m, nz + j]
                k[i, j] = acc
        for i in range(nx):
            acc = 0.0
            for m in range(nz):
                acc += k[i, m] * y[m]
            x_out[t, i] = (yaw if i == 3 else x[t, i]) + acc
        x_out[t, 3] = kk.wrap_once(x_out[t, 3])
        for i in range(nx):
            for j in range(nz):
                acc = 0.0
                for m in range(nz):
                    acc += k[i, m] * r[m, j]
                kr[i, j] = acc
            for j in range(nx):
                acc = 0.0
                for m in range(nz):
                    acc += k[i, m] * p[t, m, j]
                ap[i, j] = p[t, i, j] - acc
        for i in range(nx):
            for j in range(i, nx):
                a_kt = krk = 0.0
                for m in range(nz):
                    a_kt += ap[i, m] * k[j, m]
                    krk += kr[i, m] * k[j, m]
                p_out[t, i, j] = p_out[t, j, i] = (ap[i, j] - a_kt) + krk


def constant_velocity_tracks(n: int, seed: int) -> tuple[F64, F64, F64, F64]:
    """Covariances of a constant-velocity filter's pattern (the diagonal, and each position
    with its velocity), over many scales, with zero variances, signed zeros, and every yaw
    flip; a diagonal R."""
    rng = np.random.default_rng(seed)
    scale = 10.0 ** rng.uniform(-6, 6, n)
    p = np.zeros((n, 10, 10))
    for i in range(10):
        p[:, i, i] = rng.uniform(0.0, 3.0, n) * scale * (rng.random(n) > 0.05)
    for a in range(3):
        p[:, a, a + 7] = p[:, a + 7, a] = rng.normal(size=n) * scale * (rng.random(n) > 0.1)
    p[rng.random(n) < 0.1, 2, 5] = -0.0  # a zero of the other sign where the pattern has none
    x = rng.normal(size=(n, 10)) * 10.0 ** rng.uniform(-2, 2)
    x[:, 3] = rng.uniform(-3 * np.pi + 0.01, 3 * np.pi - 0.01, n)
    z = x[:, :7] + rng.normal(size=(n, 7)) * 10.0 ** rng.uniform(-4, 1)
    z[:, 3] = rng.uniform(-3 * np.pi + 0.01, 3 * np.pi - 0.01, n)
    z[rng.random(n) < 0.1, 1] = -0.0
    return x, p, z, np.diag(rng.uniform(1e-6, 5.0, 7))


@pytest.mark.parametrize("seed", range(6))
def test_update_on_the_constant_velocity_pattern_is_the_dense_path_bit_for_bit(seed: int) -> None:
    x, p, z, r = constant_velocity_tracks(200, seed)
    got = kk.update_all(x, p, z, r)
    want = dense_loops(x, p, z, r)
    for g, w in zip(got, want, strict=True):
        assert g.tobytes() == w.tobytes()  # every bit, the signs of zeros too


def test_update_off_the_pattern_takes_the_dense_path() -> None:
    """A cross term the pattern lacks, a non-finite innovation, a full R: still the dense
    path's numbers, bit for bit (NaN where a non-finite value meets its zeros)."""
    x, p, z, r = constant_velocity_tracks(30, 9)
    p[0, 0, 1] = p[0, 1, 0] = 0.25
    z[1, 2] = np.inf
    for rr in (r, r + 0.01 * np.eye(7, k=1) + 0.01 * np.eye(7, k=-1)):
        got = kk.update_all(x, p, z, rr)
        want = dense_loops(x, p, z, rr)
        for g, w in zip(got, want, strict=True):
            np.testing.assert_array_equal(g, w)
            assert g.tobytes() == w.tobytes()
    assert np.isnan(kk.update_all(x, p, z, r)[0][1]).any()  # inf times a zero of K
