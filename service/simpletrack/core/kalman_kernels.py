"""Compiled Kalman steps over all tracks (core/motion.py's filter; core/jit.py compiles them).

State ``[x, y, z, yaw, l, w, h, vx, vy, vz]``, measuring the first 7 (H = [I 0]).

- ``predict_all``: x = F x, P = F P F^T + Q with F = I + dt E, as row and column additions:
  the same scalar operations, in the same order, as the numpy code it replaced (bit-identical).
- ``update_all``: the reference's yaw alignment, then filterpy's update with the Joseph form,
  using H's structure instead of dense products: A P = P - K P[:7, :] and
  (A P) A^T = A P - (A P)[:, :7] K^T (A = I - K H), plus K R K^T; its upper triangle,
  mirrored. S^-1 by Gauss-Jordan with
  partial pivoting. It agrees with the dense products to rounding (~1e-15), not bit for bit;
  tests/core/test_motion.py holds it to filterpy within 1e-9.
"""

from __future__ import annotations

import math

import numpy as np
import numpy.typing as npt

from simpletrack.core.jit import helper, inline, kernel

F64 = npt.NDArray[np.float64]

__all__ = ["predict_all", "predict_row", "update_all", "update_into", "wrap_once"]

_YAW = 3
_Z = 7  # measured dimensions
_X = 10  # state dimensions
_PI = math.pi

_PREDICT = "Tuple((float64[:, ::1], float64[:, :, ::1]))(float64[:, :], float64[:, :, :], float64[:], float64[:, :])"
_UPDATE = "Tuple((float64[:, ::1], float64[:, :, ::1]))(float64[:, :], float64[:, :, :], float64[:, :], float64[:, :])"


@inline
def wrap_once(a: float) -> float:
    """motion._wrap_once on one value: into [-pi, pi) for |a| < 3 pi."""
    if a >= _PI:
        a = a - 2 * _PI
    if a < -_PI:
        a = a + 2 * _PI
    return a


@inline
def _align_yaw(predicted: float, measured: float) -> float:
    """motion.align_yaw on one pair (same operations in the same order)."""
    pred = wrap_once(predicted)
    meas = wrap_once(measured)
    diff = abs(meas - pred)
    out = pred
    if diff > _PI / 2 and diff < 3 * _PI / 2:
        turned = pred + _PI
        if turned > _PI:
            turned = turned - 2 * _PI
        if turned < -_PI:
            turned = turned + 2 * _PI
        out = turned
    if abs(meas - out) >= 3 * _PI / 2:
        out = out + (2 * _PI if meas > 0 else -2 * _PI)
    return out


@kernel(_PREDICT)
def predict_all(x: F64, p: F64, dt: F64, q: F64) -> tuple[F64, F64]:
    """(T, 10) means and (T, 10, 10) covariances one step of dt[t] ahead, one Q for all."""
    n = x.shape[0]
    x_out = np.empty((n, _X))
    p_out = np.empty((n, _X, _X))
    fp = np.empty((_X, _X))
    for t in range(n):
        predict_row(x[t], p[t], dt[t], q, x_out[t], p_out[t], fp, _X)
    return x_out, p_out


@inline
def predict_row(x: F64, p: F64, d: float, q: F64, x_out: F64, p_out: F64, fp: F64, nx: int) -> None:
    """One track's constant-velocity step of ``d`` into ``x_out``, ``p_out`` (``fp``: scratch
    of P's shape); ``nx`` states, 10 or more (those past 10 keep their values, plus Q).
    Inlined, so that a literal ``nx`` unrolls the loops (the 10-state path is the hot one:
    it is as fast as the loops written out)."""
    for i in range(nx):
        x_out[i] = x[i] + x[i + 7] * d if i < 3 else x[i]
    for i in range(nx):
        for j in range(nx):
            fp[i, j] = p[i, j] + p[i + 7, j] * d if i < 3 else p[i, j]
    for i in range(nx):
        for j in range(nx):
            v = fp[i, j] + fp[i, j + 7] * d if j < 3 else fp[i, j]
            p_out[i, j] = v + q[i, j]


@kernel(_UPDATE)
def update_all(x: F64, p: F64, z: F64, r: F64) -> tuple[F64, F64]:
    """Predicted (T, X) means and (T, X, X) covariances (X = 10, or 12 with motion models)
    corrected by (T, 7) measurements;
    yaw aligned before and wrapped after, as the reference does."""
    n = x.shape[0]
    nx = x.shape[1]
    x_out = np.empty((n, nx))
    p_out = np.empty((n, nx, nx))
    update_into(x, p, z, r, x_out, p_out)
    return x_out, p_out


@helper
def update_into(x: F64, p: F64, z: F64, r: F64, x_out: F64, p_out: F64) -> None:
    """``update_all`` writing into ``x_out`` and ``p_out`` (callable from other kernels); 10
    states (a literal width: the hot path, unrolled), or 12 with motion models' extra states
    (core/motion_kernels.py)."""
    if x.shape[1] == _X:
        _update(x, p, z, r, x_out, p_out, _X)
    else:
        _update(x, p, z, r, x_out, p_out, x.shape[1])


@inline
def _update(x: F64, p: F64, z: F64, r: F64, x_out: F64, p_out: F64, nx: int) -> None:
    n = x.shape[0]
    y = np.empty(_Z)
    aug = np.empty((_Z, 2 * _Z))  # [S | I] -> [I | S^-1]
    k = np.empty((nx, _Z))
    kr = np.empty((nx, _Z))
    ap = np.empty((nx, nx))
    for t in range(n):
        yaw = _align_yaw(x[t, _YAW], z[t, _YAW])
        for i in range(_Z):
            if i == _YAW:
                y[i] = wrap_once(z[t, i]) - yaw
            else:
                y[i] = z[t, i] - x[t, i]
        for i in range(_Z):
            for j in range(_Z):
                aug[i, j] = p[t, i, j] + r[i, j]
                aug[i, _Z + j] = 1.0 if i == j else 0.0
        for c in range(_Z):
            pivot, best = c, abs(aug[c, c])
            for i in range(c + 1, _Z):
                if abs(aug[i, c]) > best:
                    pivot, best = i, abs(aug[i, c])
            if pivot != c:
                for j in range(2 * _Z):
                    aug[c, j], aug[pivot, j] = aug[pivot, j], aug[c, j]
            inv = 1.0 / aug[c, c]
            for j in range(2 * _Z):
                aug[c, j] *= inv
            for i in range(_Z):
                f = aug[i, c]
                if i != c and f != 0.0:
                    for j in range(2 * _Z):
                        aug[i, j] -= f * aug[c, j]
        for i in range(nx):  # K = P H^T S^-1
            for j in range(_Z):
                acc = 0.0
                for m in range(_Z):
                    acc += p[t, i, m] * aug[m, _Z + j]
                k[i, j] = acc
        for i in range(nx):
            acc = 0.0
            for m in range(_Z):
                acc += k[i, m] * y[m]
            x_out[t, i] = (yaw if i == _YAW else x[t, i]) + acc
        x_out[t, _YAW] = wrap_once(x_out[t, _YAW])
        for i in range(nx):
            for j in range(_Z):
                acc = 0.0
                for m in range(_Z):
                    acc += k[i, m] * r[m, j]
                kr[i, j] = acc
            for j in range(nx):
                acc = 0.0
                for m in range(_Z):
                    acc += k[i, m] * p[t, m, j]
                ap[i, j] = p[t, i, j] - acc
        # The upper triangle, mirrored: a covariance published must be exactly symmetric.
        for i in range(nx):
            for j in range(i, nx):
                a_kt = 0.0
                krk = 0.0
                for m in range(_Z):
                    a_kt += ap[i, m] * k[j, m]
                    krk += kr[i, m] * k[j, m]
                v = (ap[i, j] - a_kt) + krk
                p_out[t, i, j] = v
                p_out[t, j, i] = v
