"""Motion models, vectorised over all tracks of a tracker.

The Kalman filter is AB3DMOT's 10-d constant-velocity filter over
``[x, y, z, yaw, l, w, h, vx, vy, vz]`` measuring the first 7. It holds no per-track state:
callers pass the stacked means (T, 10) and covariances (T, 10, 10). The arithmetic follows
``filterpy.kalman.KalmanFilter`` (predict; update with the Joseph form) so results agree with it.
"""

from __future__ import annotations

import numpy as np

from simpletrack.core.boxes import F64, YAW
from simpletrack.core.config import KalmanConfig, MotionKind, TrackerConfig
from simpletrack.core.kalman_kernels import predict_all, update_all
from simpletrack.core.motion_kernels import BICYCLE, CA, CTRA, CV

DIM_X = 10
DIM_Z = 7
_VEL = slice(7, 10)


# Each model's code in motion_kernels, and its extra states' (e0, e1) initial variance and
# process noise per frame (squared units of config.MotionKind); docs/MOTION.md says why.
MODEL_CODES = {
    MotionKind.CV: CV,
    MotionKind.CA: CA,
    MotionKind.CTRA: CTRA,
    MotionKind.BICYCLE: BICYCLE,
}
MODEL_P0: dict[MotionKind, tuple[float, float]] = {
    MotionKind.CA: (4.0, 4.0),  # 2 m/s^2
    MotionKind.CTRA: (0.25, 4.0),  # 0.5 rad/s, 2 m/s^2
    MotionKind.BICYCLE: (0.01, 4.0),  # 0.1 /m (a 10 m radius), 2 m/s^2
}
MODEL_Q: dict[MotionKind, tuple[float, float]] = {
    MotionKind.CA: (0.25, 0.25),  # 0.5 m/s^2 per frame
    MotionKind.CTRA: (0.01, 0.25),  # 0.1 rad/s, 0.5 m/s^2 per frame
    MotionKind.BICYCLE: (0.0004, 0.25),  # 0.02 /m, 0.5 m/s^2 per frame
}


def class_noise(config: TrackerConfig) -> tuple[F64, F64]:
    """Per class code: the births' covariance (n_cls, X, X) and the diagonal process noise
    (n_cls, X), X = config.state_dim. Over the 10 AB3DMOT states: the Kalman settings (or
    the class's process_noise); over the two extra ones: the model's (a 12-d table's cv rows
    keep their extra states untouched but for this noise)."""
    kal = config.kalman
    dim = config.state_dim
    n = len(config.classes)
    p0 = np.zeros((n, dim, dim))
    q = np.zeros((n, dim))
    for code, c in enumerate(config.classes.values()):
        diag = np.full(dim, kal.p0_measured)
        diag[_VEL] = kal.p0_velocity
        q[code] = kal.q
        if c.process_noise is not None:
            q[code, :DIM_Z], q[code, DIM_Z:DIM_X] = c.process_noise
        if dim > DIM_X:
            extra_p0 = MODEL_P0.get(c.motion_model, (kal.p0_measured, kal.p0_measured))
            extra_q = c.model_noise or MODEL_Q.get(c.motion_model, (kal.q, kal.q))
            diag[DIM_X:] = extra_p0
            q[code, DIM_X:] = extra_q
        p0[code] = np.diag(diag)
    return p0, q


def _wrap_once(a: F64) -> F64:
    """The reference's single-step wrap into [-pi, pi): valid for |a| < 3 pi."""
    a = np.where(a >= np.pi, a - 2 * np.pi, a)
    return np.where(a < -np.pi, a + 2 * np.pi, a)


def transition(dt: F64) -> F64:
    """F(dt) for each track: (T, 10, 10)."""
    f = np.broadcast_to(np.eye(DIM_X), (dt.shape[0], DIM_X, DIM_X)).copy()
    f[:, [0, 1, 2], [7, 8, 9]] = dt[:, None]
    return f


class KalmanFilter:
    """Constant-velocity Kalman filter with AB3DMOT's noise defaults."""

    def __init__(self, config: KalmanConfig) -> None:
        self.config = config
        self.q = np.eye(DIM_X) * config.q
        self.r = np.eye(DIM_Z) * config.r
        p0 = np.full(DIM_X, config.p0_measured)
        p0[_VEL] = config.p0_velocity
        self.p0 = np.diag(p0)

    def initiate(self, measurement: F64) -> tuple[F64, F64]:
        n = measurement.shape[0]
        x = np.zeros((n, DIM_X))
        x[:, :DIM_Z] = measurement
        return x, np.broadcast_to(self.p0, (n, DIM_X, DIM_X)).copy()

    def predict(self, x: F64, p: F64, dt: F64) -> tuple[F64, F64]:
        """One step of dt (per track) with one Q: x = F x, P = F P F^T + Q (compiled:
        core/kalman_kernels.py)."""
        return predict_all(x, p, np.asarray(dt, dtype=np.float64), self.q)

    def innovation(self, p: F64) -> F64:
        """S = H P H^T + R, (T, 7, 7)."""
        return np.asarray(p[:, :DIM_Z, :DIM_Z] + self.r, dtype=np.float64)

    def update(self, x: F64, p: F64, z: F64) -> tuple[F64, F64]:
        """Correct predicted states (T, 10) with measurements (T, 7), after the reference's
        orientation correction, and wrap the yaw afterwards (compiled: core/kalman_kernels.py,
        the Joseph form as filterpy computes it)."""
        return update_all(x, p, np.asarray(z, dtype=np.float64), self.r)


def align_yaw(predicted: F64, measured: F64) -> F64:
    """The reference's orientation correction of the predicted yaw before an update: turn it
    by pi when the two headings are more than 90 degrees apart, then bring values that are
    still >= 270 degrees apart together by 2 pi."""
    pred = _wrap_once(predicted)
    meas = _wrap_once(measured)
    diff = np.abs(meas - pred)
    flip = (diff > np.pi / 2) & (diff < 3 * np.pi / 2)
    turned = pred + np.pi
    turned = np.where(turned > np.pi, turned - 2 * np.pi, turned)
    turned = np.where(turned < -np.pi, turned + 2 * np.pi, turned)
    out = np.where(flip, turned, pred)
    # The reference re-reads the (possibly turned) state here: the check is "still" far apart.
    far = np.abs(meas - out) >= 3 * np.pi / 2
    return np.asarray(
        np.where(far, out + np.where(meas > 0, 2 * np.pi, -2 * np.pi), out), dtype=np.float64
    )


def predicted_boxes(x_pred: F64) -> F64:
    """The (T, 7) boxes of predicted states, yaw wrapped as the reference reports them."""
    boxes = x_pred[:, :DIM_Z].copy()
    boxes[:, YAW] = _wrap_once(boxes[:, YAW])
    return boxes


class ConstantVelocity:
    """CenterPoint-style motion: the detector's velocity carries the box; no filtering."""

    def initiate(self, measurement: F64, velocity: F64 | None) -> F64:
        x = np.zeros((measurement.shape[0], DIM_X))
        x[:, :DIM_Z] = measurement
        if velocity is not None:
            x[:, 7:9] = velocity
        return x

    def predict(self, x: F64, dt: F64) -> F64:
        out = x.copy()
        out[:, :3] += x[:, 7:10] * dt[:, None]
        return out

    def update(self, measurement: F64, velocity: F64 | None, previous: F64) -> F64:
        x = previous.copy()
        x[:, :DIM_Z] = measurement
        x[:, YAW] = _wrap_once(x[:, YAW])
        if velocity is not None:
            x[:, 7:9] = velocity
        return x
