"""Which boxes a sensor cannot see because nearer ones hide them: a line-of-sight sensor
(lidar, camera) that misses an object behind a bus has learnt nothing about it.

Seen from the sensor (the origin of the frame the boxes are in), each box covers an angular
interval (its BEV outline's bearings); the share of it covered by nearer boxes' intervals is
its occlusion (summed, an upper bound when the hiders overlap each other, capped at 1).
Pure: boxes in, fractions out.
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt

from simpletrack.core.boxes import wrap_angle

F64 = npt.NDArray[np.float64]
_SIGNS_L = np.array([1.0, 1.0, -1.0, -1.0])
_SIGNS_W = np.array([1.0, -1.0, -1.0, 1.0])


def occlusion(xy: F64, yaw: F64, length: F64, width: F64) -> F64:
    """Fraction of each box's angular extent hidden behind nearer boxes, seen from (0, 0):
    centres ``xy`` (N, 2), headings and BEV sizes (N,)."""
    n = xy.shape[0]
    if n == 0:
        return np.zeros(0)
    x, y = xy[:, 0], xy[:, 1]
    dist = np.hypot(x, y)
    bearing = np.arctan2(y, x)
    c, s = np.cos(yaw), np.sin(yaw)
    hl, hw = length / 2, width / 2
    cx = x[:, None] + _SIGNS_L * (hl * c)[:, None] - _SIGNS_W * (hw * s)[:, None]
    cy = y[:, None] + _SIGNS_L * (hl * s)[:, None] + _SIGNS_W * (hw * c)[:, None]
    half = np.abs(wrap_angle(np.arctan2(cy, cx) - bearing[:, None])).max(axis=1)
    d = wrap_angle(bearing[None, :] - bearing[:, None])  # [i, j]: bearing of j relative to i
    lo = np.maximum(-half[:, None], d - half[None, :])
    hi = np.minimum(half[:, None], d + half[None, :])
    overlap = np.clip(hi - lo, 0.0, None)
    nearer = dist[None, :] < dist[:, None]
    hidden = (overlap * nearer).sum(axis=1) / np.maximum(2 * half, 1e-9)
    return np.asarray(np.minimum(hidden, 1.0), dtype=np.float64)


__all__ = ["occlusion"]
