"""Compiled Kalman steps over all tracks (core/motion.py's filter; core/jit.py compiles them).

State ``[x, y, z, yaw, l, w, h, vx, vy, vz]``, measuring the first 7 (H = [I 0]).

- ``predict_all``: x = F x, P = F P F^T + Q with F = I + dt E, as row and column additions:
  the same scalar operations, in the same order, as the numpy code it replaced (bit-identical).
- ``update_all``: the reference's yaw alignment, then filterpy's update with the Joseph form,
  using H's structure instead of dense products: A P = P - K P[:7, :] and
  (A P) A^T = A P - (A P)[:, :7] K^T (A = I - K H), plus K R K^T; its upper triangle,
  mirrored. S^-1 by Gauss-Jordan with
  partial pivoting. It agrees with the dense products to rounding (~1e-15), not bit for bit;
  tests/core/test_motion.py holds it to filterpy within 1e-9. A track whose P has a
  constant-velocity filter's pattern (16 of its 100 cells: what a diagonal P0, Q and R keep,
  as every preset's 10-state filter has them), with a diagonal R, takes ``_update_blocks``:
  the same arithmetic without its products by exact zeros, bit-identical, ~20 products
  instead of ~3,000.
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
    diagonal_r = nx == _X and _diagonal(r)
    for t in range(n):
        yaw = _align_yaw(x[t, _YAW], z[t, _YAW])
        for i in range(_Z):
            if i == _YAW:
                y[i] = wrap_once(z[t, i]) - yaw
            else:
                y[i] = z[t, i] - x[t, i]
        if diagonal_r and _blocks_only(p[t], y):
            _update_blocks(x[t], p[t], y, yaw, r, x_out[t], p_out[t])
            continue
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


# A constant-velocity filter's P has its diagonal and the cells pairing each position i < 3
# with its velocity i + 7, nothing else (the predict and the update keep that pattern from a
# diagonal P0, Q and R); a track's update on such a P is ~20 of the dense path's ~3,000
# products. (The predict stays as it is: on the pattern alone it measured no faster.)
_PAIRS = 3


@inline
def _diagonal(r: F64) -> bool:
    """R is diagonal, its diagonal finite and positive."""
    for i in range(_Z):
        if not (math.isfinite(r[i, i]) and r[i, i] > 0.0):
            return False
        for j in range(_Z):
            if i != j and r[i, j] != 0.0:
                return False
    return True


@inline
def _on_pattern(i: int, j: int) -> bool:
    return i == j or (i < _PAIRS and j == i + 7) or (j < _PAIRS and i == j + 7)


@inline
def _blocks_only(p: F64, y: F64) -> bool:
    """P (10 x 10) has the constant-velocity pattern, finite, its diagonal not negative (with
    ``_diagonal``'s R, S > 0), every other cell zero; and the innovation y is finite (a
    non-finite value times one of the dense path's zeros is NaN: only that path gives it)."""
    for i in range(_X):
        for j in range(_X):
            v = p[i, j]
            if _on_pattern(i, j):
                if not math.isfinite(v) or (i == j and v < 0.0):
                    return False
            elif v != 0.0:
                return False
    for i in range(_Z):  # noqa: SIM110 (a loop numba compiles, not a generator)
        if not math.isfinite(y[i]):
            return False
    return True


@inline
def _update_blocks(x: F64, p: F64, y: F64, yaw: float, r: F64, x_out: F64, p_out: F64) -> None:
    """One track's update on a P of ``_blocks_only``'s pattern, bit for bit the dense path's:
    each of the dense sums has one product that is not an exact zero, so each is computed here
    as ``0.0 + product`` (what the dense sum of it and those zeros rounds to, -0.0 included),
    in the same expressions; every other cell of P is the +0.0 those sums give. S = P[:7, :7]
    + R is diagonal, so the Gauss-Jordan inverse is 1 / S[a, a] (no pivot, no elimination)."""
    for i in range(_X):
        for j in range(_X):
            p_out[i, j] = 0.0
    for a in range(_Z):
        inv = 1.0 / (p[a, a] + r[a, a])
        k_a = 0.0 + p[a, a] * inv  # K[a, a]
        x_out[a] = (yaw if a == _YAW else x[a]) + (0.0 + k_a * y[a])
        kr_a = 0.0 + k_a * r[a, a]
        ap_aa = p[a, a] - (0.0 + k_a * p[a, a])
        v = (ap_aa - (0.0 + ap_aa * k_a)) + (0.0 + kr_a * k_a)
        p_out[a, a] = v
        if a < _PAIRS:  # the position's velocity b: K[b, a], and the cells (a, b), (b, b)
            b = a + 7
            k_b = 0.0 + p[b, a] * inv
            x_out[b] = x[b] + (0.0 + k_b * y[a])
            kr_b = 0.0 + k_b * r[a, a]
            ap_ab = p[a, b] - (0.0 + k_a * p[a, b])
            ap_ba = p[b, a] - (0.0 + k_b * p[a, a])
            ap_bb = p[b, b] - (0.0 + k_b * p[a, b])
            v = (ap_ab - (0.0 + ap_aa * k_b)) + (0.0 + kr_a * k_b)
            p_out[a, b] = v
            p_out[b, a] = v
            p_out[b, b] = (ap_bb - (0.0 + ap_ba * k_b)) + (0.0 + kr_b * k_b)
    x_out[_YAW] = wrap_once(x_out[_YAW])
