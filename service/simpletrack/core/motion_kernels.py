"""Compiled prediction of tracks whose classes have motion models (config.MotionKind).

The state is ``[x, y, z, yaw, l, w, h, vx, vy, vz, e0, e1]`` (12; docs/MOTION.md). A class
with ``cv`` moves as ``kalman_kernels.predict_all`` moves it (the same scalar operations:
its rows are bit-identical to a 10-d tracker's); the other models move the bird's-eye state
along a circular arc (``_move``) and propagate the covariance through the model's Jacobian,
taken by central differences (an extended Kalman filter). The arc's chord is exact for a
constant turn rate or curvature at constant speed (a car on a circle) and for a constant
acceleration along a straight line (a cyclist braking to a stop), which
tests/core/test_motion_models.py holds to hand-computed positions.

The velocity vector, not the box's yaw, carries the heading of motion: a detector's yaw can
be off by pi from one frame to the next (the reference's orientation correction turns the
prediction to match), and the velocity's direction is not. The box's yaw turns with the
motion, so a measured yaw informs the turn rate as the positions do.
"""

from __future__ import annotations

import math

import numpy as np
import numpy.typing as npt

from simpletrack.core.jit import helper, kernel
from simpletrack.core.kalman_kernels import predict_row

F64 = npt.NDArray[np.float64]
I32 = npt.NDArray[np.int32]
I64 = npt.NDArray[np.int64]

__all__ = ["BICYCLE", "CA", "CTRA", "CV", "MIN_SPEED", "move", "predict_models"]

# Model codes, config.MotionKind's order.
CV, CA, CTRA, BICYCLE = range(4)
# Acceleration acts along the velocity; below this speed (m/s) its direction is poorly known,
# so it acts as if the track moved this fast (the speed change and the Jacobian stay bounded).
MIN_SPEED = 0.5
_X = 12
_YAW = 3
_PI = math.pi
# The columns of the Jacobian that differ from the identity (velocity, e0, e1).
_COLS = (7, 8, 9, 10, 11)

_PREDICT = (
    "Tuple((float64[:, ::1], float64[:, :, ::1]))"
    "(float64[:, :], float64[:, :, :], float64[:], int32[:], int64[:], float64[:, :])"
)


@helper
def move(model: int, x: F64, tau: float, out: F64) -> None:
    """``x`` (12,) moved ``tau`` seconds ahead by ``model`` (not CV), into ``out``; yaw not
    wrapped (the caller wraps once, so that differences of it stay smooth)."""
    for i in range(_X):
        out[i] = x[i]
    vx, vy = x[7], x[8]
    out[2] = x[2] + x[9] * tau
    if model == CA:
        ax, ay = x[10], x[11]
        out[0] = x[0] + vx * tau + 0.5 * ax * tau * tau
        out[1] = x[1] + vy * tau + 0.5 * ay * tau * tau
        out[7] = vx + ax * tau
        out[8] = vy + ay * tau
        return
    speed = math.hypot(vx, vy)
    a = x[11]
    gain = 1.0 + a * tau / max(speed, MIN_SPEED)  # the speed's factor over tau
    if gain >= 0.0:
        k = tau * (1.0 + gain) / 2.0  # distance / speed: the mean speed's time
    else:  # stops within tau: the distance to the stop
        k = -max(speed, MIN_SPEED) / a / 2.0
        gain = 0.0
    turn = x[10] * tau if model == CTRA else x[10] * k * speed  # bicycle: curvature x distance
    half = 0.5 * turn
    sinc = 1.0 - half * half / 6.0 if abs(half) < 1e-4 else math.sin(half) / half
    ch, sh = math.cos(half), math.sin(half)
    m = k * sinc  # the chord of the arc, along the velocity turned by half the turn
    out[0] = x[0] + m * (ch * vx - sh * vy)
    out[1] = x[1] + m * (sh * vx + ch * vy)
    ct, st = math.cos(turn), math.sin(turn)
    out[7] = gain * (ct * vx - st * vy)
    out[8] = gain * (st * vx + ct * vy)
    out[_YAW] = x[_YAW] + turn


@helper
def _wrap(a: float) -> float:
    """Into [-pi, pi), however far out (a turn rate can wind a coasting track's yaw)."""
    return a - 2.0 * _PI * math.floor((a + _PI) / (2.0 * _PI))


@kernel(_PREDICT)
def predict_models(x: F64, p: F64, dt: F64, cls: I32, model: I64, q: F64) -> tuple[F64, F64]:
    """(T, X) means and (T, X, X) covariances one step of dt[t] ahead, each track by its
    class's model (``model[cls]``), with the diagonal process noise ``q[cls]`` (n_cls, X);
    X = 12, or 10 when every model is cv."""
    n = x.shape[0]
    nx = x.shape[1]  # 12; 10 when every class is cv (a per-class process noise alone)
    x_out = np.empty((n, nx))
    p_out = np.empty((n, nx, nx))
    fp = np.empty((nx, nx))
    e = np.empty((nx, 5))  # F - I in the columns _COLS
    plus = np.empty(nx)
    minus = np.empty(nx)
    probe = np.empty(nx)
    q_full = np.zeros((q.shape[0], nx, nx))
    for c in range(q.shape[0]):
        for i in range(nx):
            q_full[c, i, i] = q[c, i]
    for t in range(n):
        d = dt[t]
        c = cls[t]
        mo = model[c]
        if mo == CV:  # kalman_kernels.predict_all's step, with the class's Q
            predict_row(x[t], p[t], d, q_full[c], x_out[t], p_out[t], fp, nx)
            continue
        move(mo, x[t], d, plus)
        for i in range(nx):
            x_out[t, i] = plus[i]
        x_out[t, _YAW] = _wrap(plus[_YAW])
        for a in range(5):
            col = _COLS[a]
            h = 1e-6 * max(1.0, abs(x[t, col]))
            for i in range(nx):
                probe[i] = x[t, i]
            probe[col] = x[t, col] + h
            move(mo, probe, d, plus)
            probe[col] = x[t, col] - h
            move(mo, probe, d, minus)
            for i in range(nx):
                e[i, a] = (plus[i] - minus[i]) / (2.0 * h) - (1.0 if i == col else 0.0)
        # F P F^T with F = I + E, E zero outside _COLS: FP = P + E P, then FP + FP E^T.
        for i in range(nx):
            for j in range(nx):
                acc = p[t, i, j]
                for a in range(5):
                    acc += e[i, a] * p[t, _COLS[a], j]
                fp[i, j] = acc
        for i in range(nx):
            for j in range(i, nx):
                acc = fp[i, j]
                for a in range(5):
                    acc += fp[i, _COLS[a]] * e[j, a]
                if i == j:
                    acc += q[c, i]
                p_out[t, i, j] = acc
                p_out[t, j, i] = acc
    return x_out, p_out
