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

from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

F64 = npt.NDArray[np.float64]
I32 = npt.NDArray[np.int32]

SEARCH_M = 30.0  # pairs further apart than this do not vote
BIN_M = 1.0
_BINS = int(2 * SEARCH_M / BIN_M)
_CENTRE = _BINS // 2  # the cell whose lower corner is (0, 0)
DECAY = 0.7  # weight of the votes so far against the newest frame's
MIN_VOTES = 6.0  # decayed votes a peak needs before it means anything
PAIR_GATE_M = 4.0  # a pair (after the offset is taken out) fits the time estimate within this
MIN_EXCITATION = 200.0  # sum of squared speeds (m/s)^2 before the time offset means anything


@dataclass(frozen=True, slots=True)
class MonitorState:
    votes: F64  # (_BINS, _BINS) decayed offset votes
    normal: F64  # (3, 3) decayed normal matrix of the (bx, by, delta) fit
    rhs: F64  # (3,)

    @classmethod
    def empty(cls) -> MonitorState:
        return cls(np.zeros((_BINS, _BINS)), np.zeros((3, 3)), np.zeros(3))


@dataclass(frozen=True, slots=True)
class Estimate:
    """What the votes say now. ``offset_m`` the peak's (x, y) (None: too few votes);
    ``agree`` whether this frame alone put its strongest vote near (0, 0) with at least
    ``MIN_VOTES`` pairs close there; ``delta_s`` the clock offset (None: too little motion)."""

    offset_m: tuple[float, float] | None
    peak_votes: float
    zero_votes: float
    agree: bool
    delta_s: float | None


def _region(votes: F64, i: int, j: int) -> float:
    """Votes in the 3 x 3 cells around (i, j): an offset near a cell border counts whole."""
    return float(votes[max(i - 1, 0) : i + 2, max(j - 1, 0) : j + 2].sum())


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
    d = det_xy[:, None, :] - trk_xy[None, :, :]  # (N, M, 2): detection minus track
    same = det_cls[:, None] == trk_cls[None, :]
    near = same & (np.abs(d) < SEARCH_M).all(axis=2)
    off = d[near]
    cells = np.floor(off / BIN_M).astype(np.int64) + _CENTRE
    frame_votes = np.zeros((_BINS, _BINS))
    np.add.at(frame_votes, (cells[:, 0], cells[:, 1]), 1.0)
    votes = state.votes * DECAY + frame_votes

    pi, pj = np.unravel_index(int(np.argmax(votes)), votes.shape)
    peak = _region(votes, int(pi), int(pj))
    zero = _region(votes, _CENTRE, _CENTRE) + _region(votes, _CENTRE - 1, _CENTRE - 1)
    offset: tuple[float, float] | None = None
    if peak >= MIN_VOTES:
        sel = (np.abs(cells[:, 0] - pi) <= 1) & (np.abs(cells[:, 1] - pj) <= 1)
        if sel.any():  # refined by this frame's pairs in the peak region
            mean = off[sel].mean(axis=0)
            offset = (float(mean[0]), float(mean[1]))
        else:
            offset = ((pi - _CENTRE + 0.5) * BIN_M, (pj - _CENTRE + 0.5) * BIN_M)
    fi, fj = np.unravel_index(int(np.argmax(frame_votes)), frame_votes.shape)
    frame_zero = _region(frame_votes, _CENTRE, _CENTRE) + _region(
        frame_votes, _CENTRE - 1, _CENTRE - 1
    )
    near_zero = abs(int(fi) - _CENTRE) <= 2 and abs(int(fj) - _CENTRE) <= 2
    agree = bool(near_zero and frame_zero >= MIN_VOTES / 2)

    normal, rhs = _time_fit(d, same, trk_vel, offset)
    normal = state.normal * DECAY + normal
    rhs = state.rhs * DECAY + rhs
    delta = None
    if normal[2, 2] >= MIN_EXCITATION:
        try:
            delta = float(np.linalg.solve(normal + np.eye(3) * 1e-6, rhs)[2])
        except np.linalg.LinAlgError:
            delta = None
    return MonitorState(votes, normal, rhs), Estimate(offset, peak, zero, agree, delta)


def _time_fit(
    d: F64, same: npt.NDArray[np.bool_], trk_vel: F64, offset: tuple[float, float] | None
) -> tuple[F64, F64]:
    """The normal equations of ``residual = b + v * delta`` over the mutual nearest pairs
    within ``PAIR_GATE_M`` once the offset is taken out."""
    normal, rhs = np.zeros((3, 3)), np.zeros(3)
    if d.size == 0:
        return normal, rhs
    shift = np.zeros(2) if offset is None else np.asarray(offset)
    r = d - shift
    dist = np.where(same, np.hypot(r[..., 0], r[..., 1]), np.inf)
    best_t = np.argmin(dist, axis=1)  # each detection's nearest track
    best_d = np.argmin(dist, axis=0)  # each track's nearest detection
    rows = np.arange(dist.shape[0])
    mutual = (best_d[best_t] == rows) & (dist[rows, best_t] <= PAIR_GATE_M)
    di, ti = rows[mutual], best_t[mutual]
    if di.size == 0:
        return normal, rhs
    res = d[di, ti]  # (K, 2) with the offset left in: b is fitted
    v = trk_vel[ti]
    # Rows: x residual = bx + vx delta; y residual = by + vy delta.
    k = di.size
    a = np.zeros((2 * k, 3))
    a[:k, 0] = 1.0
    a[k:, 1] = 1.0
    a[:k, 2] = v[:, 0]
    a[k:, 2] = v[:, 1]
    y = np.concatenate([res[:, 0], res[:, 1]])
    return a.T @ a, a.T @ y


__all__ = ["Estimate", "MonitorState", "observe"]
