"""Is a sensor where its frames say it is, when they say it was? Its detections against the
tracks its vehicle's trusted sensors keep, frame by frame, before the frame is applied.

Two estimates, both decayed over frames (the newest frame weighs most):

- **Offset** (extrinsic): every same-class pair (detection, track) closer than ``SEARCH_M``
  votes for its BEV offset in a grid of ``BIN_M`` cells (a Hough vote). Detections of a
  well-placed sensor pile up around (0, 0); a sensor mounted 20 m off piles them around
  (20, 0) whatever the scene, while wrong pairs spread thinly over the grid.
- **Time offset** (clock): pairs close after the offset is taken out fit
  ``residual = b + velocity * delta`` (least squares over x and y): a sensor whose stamps
  run ``delta`` seconds behind its captures shows every moving object ``velocity * delta``
  ahead of where the tracks predict it.

Pure: arrays in, an estimate out; the caller decides what to do with it.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
import numpy.typing as npt

from simpletrack.core import calibration_kernels as kernels

F64 = npt.NDArray[np.float64]
I32 = npt.NDArray[np.int32]

SEARCH_M = 30.0  # pairs further apart than this do not vote
BIN_M = 1.0
_BINS = int(2 * SEARCH_M / BIN_M)
_CENTRE = _BINS // 2  # the cell whose lower corner is (0, 0)
DECAY = 0.7  # weight of the votes so far against the newest frame's
TIME_DECAY = 0.95  # the same for the time fit: a noisy sensor's residuals need many frames
MIN_VOTES = 6.0  # decayed votes a peak needs before it means anything
PAIR_GATE_M = 4.0  # a pair (after the offset is taken out) fits the time estimate within this
MIN_EXCITATION = 200.0  # sum of squared speeds (m/s)^2 before the time offset means anything


@dataclass(frozen=True, slots=True)
class MonitorState:
    votes: F64  # (_BINS, _BINS) decayed offset votes
    normal: F64  # (3, 3) decayed normal matrix of the (bx, by, delta) fit
    rhs: F64  # (3,)
    sums: F64 = field(default_factory=lambda: np.zeros(2))  # decayed sum of y^2, and rows

    @classmethod
    def empty(cls) -> MonitorState:
        return cls(np.zeros((_BINS, _BINS)), np.zeros((3, 3)), np.zeros(3), np.zeros(2))


@dataclass(frozen=True, slots=True)
class Estimate:
    """What the votes say now. ``offset_m`` the peak's (x, y) (None: too few votes);
    ``agree`` whether this frame alone put its strongest vote near (0, 0) with at least
    ``MIN_VOTES`` pairs close there; ``delta_s`` the clock offset (None: too little motion)
    and ``delta_se`` its standard error (the residuals' scatter over the motion seen)."""

    offset_m: tuple[float, float] | None
    peak_votes: float
    zero_votes: float
    agree: bool
    delta_s: float | None
    delta_se: float = math.inf


def observe(
    state: MonitorState,
    det_xy: F64,
    det_cls: I32,
    trk_xy: F64,
    trk_vel: F64,
    trk_cls: I32,
) -> tuple[MonitorState, Estimate]:
    """Vote with one frame: detections (N, 2) in the tracking frame, the trusted tracks'
    predicted centres (M, 2) and velocities (M, 2) at the frame's stamp."""
    det_cls = np.asarray(det_cls, dtype=np.int32)
    trk_cls = np.asarray(trk_cls, dtype=np.int32)
    off = kernels.voting_pairs(det_xy, det_cls, trk_xy, trk_cls, SEARCH_M)
    votes, v = kernels.offset_votes(off, state.votes, DECAY, BIN_M)
    pi, pj, peak, zero, pairs, mx, my, fi, fj, frame_zero = v.tolist()
    offset: tuple[float, float] | None = None
    if peak >= MIN_VOTES:  # refined by this frame's pairs in the peak region, if any
        cell = ((pi - _CENTRE + 0.5) * BIN_M, (pj - _CENTRE + 0.5) * BIN_M)
        offset = (mx, my) if pairs else cell
    near_zero = abs(fi - _CENTRE) <= 2 and abs(fj - _CENTRE) <= 2
    agree = bool(near_zero and frame_zero >= MIN_VOTES / 2)

    sx, sy = (0.0, 0.0) if offset is None else offset
    fit = kernels.time_fit(det_xy, det_cls, trk_xy, trk_vel, trk_cls, sx, sy, PAIR_GATE_M)
    normal, rhs, sums = fit[:9].reshape(3, 3), fit[9:12], fit[12:]
    normal = state.normal * TIME_DECAY + normal
    rhs = state.rhs * TIME_DECAY + rhs
    sums = state.sums * TIME_DECAY + sums
    delta, se = None, math.inf
    if normal[2, 2] >= MIN_EXCITATION and sums[1] > 3:
        try:
            inv = np.linalg.inv(normal + np.eye(3) * 1e-6)
        except np.linalg.LinAlgError:
            inv = None
        if inv is not None:
            theta = inv @ rhs
            delta = float(theta[2])
            # Residual variance of the fit, from the running sums (y'y - theta' X'y).
            var = max(float(sums[0] - theta @ rhs), 0.0) / (sums[1] - 3)
            se = math.sqrt(var * max(float(inv[2, 2]), 0.0))
    state = MonitorState(votes, normal, rhs, sums)
    return state, Estimate(offset, peak, zero, agree, delta, se)


__all__ = ["Estimate", "MonitorState", "observe"]
