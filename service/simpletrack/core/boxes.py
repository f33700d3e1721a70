"""Struct-of-arrays box batches: one row per box, columns as numpy arrays."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

F64 = npt.NDArray[np.float64]
I32 = npt.NDArray[np.int32]
Bool = npt.NDArray[np.bool_]

# Column order of Boxes.params: centre, yaw, size (the Kalman filter's measured state).
X, Y, Z, YAW, L, W, H = range(7)
CENTER = slice(X, Z + 1)  # x, y, z
SIZE = slice(L, H + 1)  # l, w, h


@dataclass(frozen=True, slots=True)
class Boxes:
    """N boxes: ``params`` (N, 7) = x, y, z, yaw, l, w, h; ``score`` (N,); ``cls`` (N,) class
    codes (indices into the tracker config's class list); optional ``velocity`` (N, 2)."""

    params: F64
    score: F64
    cls: I32
    velocity: F64 | None = None

    def __post_init__(self) -> None:
        n = self.params.shape[0]
        if self.params.ndim != 2 or self.params.shape[1] != 7:
            raise ValueError(f"params must be (N, 7), got {self.params.shape}")
        if self.score.shape != (n,) or self.cls.shape != (n,):
            raise ValueError(f"score {self.score.shape} and cls {self.cls.shape} must be ({n},)")
        if self.velocity is not None and self.velocity.shape != (n, 2):
            raise ValueError(f"velocity must be ({n}, 2), got {self.velocity.shape}")

    @classmethod
    def empty(cls, with_velocity: bool = False) -> Boxes:
        return cls(
            params=np.zeros((0, 7)),
            score=np.zeros(0),
            cls=np.zeros(0, dtype=np.int32),
            velocity=np.zeros((0, 2)) if with_velocity else None,
        )

    @classmethod
    def from_arrays(
        cls,
        params: npt.ArrayLike,
        score: npt.ArrayLike,
        classes: npt.ArrayLike,
        velocity: npt.ArrayLike | None = None,
    ) -> Boxes:
        p = np.asarray(params, dtype=np.float64).reshape(-1, 7)
        return cls(
            params=p,
            score=np.asarray(score, dtype=np.float64).reshape(-1),
            cls=np.asarray(classes, dtype=np.int32).reshape(-1),
            velocity=None
            if velocity is None
            else np.asarray(velocity, dtype=np.float64).reshape(-1, 2),
        )

    def __len__(self) -> int:
        return int(self.params.shape[0])

    def take(self, index: npt.ArrayLike) -> Boxes:
        """Rows by integer index array or boolean mask (always a copy)."""
        idx = np.asarray(index)
        return Boxes(
            params=self.params[idx],
            score=self.score[idx],
            cls=self.cls[idx],
            velocity=None if self.velocity is None else self.velocity[idx],
        )

    def valid_mask(self) -> Bool:
        """Boxes with positive, finite sizes and finite everything else."""
        finite = np.isfinite(self.params).all(axis=1) & np.isfinite(self.score)
        positive = self.params[:, L:].min(axis=1, initial=np.inf) > 0
        return np.asarray(finite & positive, dtype=np.bool_)

    @property
    def x(self) -> F64:
        return self.params[:, X]

    @property
    def y(self) -> F64:
        return self.params[:, Y]

    @property
    def z(self) -> F64:
        return self.params[:, Z]

    @property
    def yaw(self) -> F64:
        return self.params[:, YAW]

    @property
    def l(self) -> F64:  # noqa: E743 - the spec's name for the length column
        return self.params[:, L]

    @property
    def w(self) -> F64:
        return self.params[:, W]

    @property
    def h(self) -> F64:
        return self.params[:, H]


def wrap_angle(a: F64) -> F64:
    """Wrap angles into [-pi, pi)."""
    return np.asarray((a + np.pi) % (2 * np.pi) - np.pi, dtype=np.float64)


def transform_boxes(boxes: Boxes, pose: F64) -> Boxes:
    """Apply a 4x4 rigid transform (e.g. sensor -> world) to centres, yaws and velocities."""
    rot = pose[:3, :3]
    params = boxes.params.copy()
    params[:, :3] = boxes.params[:, :3] @ rot.T + pose[:3, 3]
    params[:, YAW] = wrap_angle(boxes.params[:, YAW] + np.arctan2(rot[1, 0], rot[0, 0]))
    velocity = None
    if boxes.velocity is not None:
        velocity = boxes.velocity @ rot[:2, :2].T
    return Boxes(params=params, score=boxes.score.copy(), cls=boxes.cls.copy(), velocity=velocity)
