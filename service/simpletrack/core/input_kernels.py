"""What a detection frame's columns go through before the tracker, in compiled calls.

``detection_extents``: the decoder judges a frame's columns by their extents (finite, within
bounds, sizes positive, class indices in the table; the plausibility checks read them too): a
dozen numpy reductions over a few hundred values each, where the call costs more than the
values, with the interpreter's lock held throughout. This walks the six columns once, the
lock let go; wire/convert.py ``detection_extents`` hands it to the decoder, which falls back
to its own reductions for a frame it finds anything wrong with (so every refusal is the one
it always was).

``detection_rows``: the tracker's columns of the boxes it tracks (float64 ``params`` in the
core's order, scores, codes, velocities), the rows of ignored classes left out, where
wire/convert.py ``frame_from_wire`` took ten numpy calls; the same values (float32 to float64
is exact), the same rows in the same order.
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt

from simpletrack.core.boxes import YAW, H, L, W, X, Y, Z
from simpletrack.core.jit import helper, kernel

__all__ = ["detection_extents", "detection_rows"]

F64 = npt.NDArray[np.float64]

# The decoder's columns are views of the message's bytes: read-only (a writable array passes
# too).
_F32_2D = "Array(float32, 2, 'C', readonly=True)"
_F32_1D = "Array(float32, 1, 'C', readonly=True)"
_F64_1D = "Array(float64, 1, 'C', readonly=True)"
_I32_1D = "Array(int32, 1, 'C', readonly=True)"
_SIGNATURE = f"float64[:, ::1]({_F32_2D}, {_F32_2D}, {_F32_1D}, {_F64_1D}, {_F32_2D}, {_I32_1D})"
_ROWS = (
    "Tuple((float64[:, ::1], float64[::1], int32[::1], float64[:, ::1]))"
    f"({_F32_2D}, {_F32_1D}, {_F32_2D}, {_F64_1D}, {_I32_1D}, {_F32_2D})"
)


@helper
def _extent(values: npt.NDArray[np.generic], out: F64, row: int) -> None:
    """Least and greatest into ``out[row]``; both NaN where a value is NaN (numpy's
    reductions propagate it). ``values`` has at least one value."""
    lo = hi = np.float64(values[0])
    nan = False
    for v in values:
        x = np.float64(v)
        if x != x:
            nan = True
        elif x < lo:
            lo = x
        elif x > hi:
            hi = x
    out[row, 0] = np.nan if nan else lo
    out[row, 1] = np.nan if nan else hi


@kernel(_SIGNATURE)
def detection_extents(
    center: npt.NDArray[np.float32],
    size: npt.NDArray[np.float32],
    yaw: npt.NDArray[np.float32],
    score: F64,
    velocity: npt.NDArray[np.float32],
    class_index: npt.NDArray[np.int32],
) -> F64:
    """(6, 2): the (least, greatest) of centre, size, yaw, score, velocity and class index, in
    that order, over every row and axis; columns of at least one row (velocity may have none:
    its row is then NaN)."""
    out = np.full((6, 2), np.nan)
    _extent(center.reshape(center.size), out, 0)
    _extent(size.reshape(size.size), out, 1)
    _extent(yaw, out, 2)
    _extent(score, out, 3)
    if velocity.size:
        _extent(velocity.reshape(velocity.size), out, 4)
    _extent(class_index, out, 5)
    return out


@kernel(_ROWS)
def detection_rows(
    center: npt.NDArray[np.float32],
    yaw: npt.NDArray[np.float32],
    size: npt.NDArray[np.float32],
    score: F64,
    codes: npt.NDArray[np.int32],
    velocity: npt.NDArray[np.float32],
) -> tuple[F64, F64, npt.NDArray[np.int32], F64]:
    """(params (k, 7), score, codes, velocity (k, 2), or (0, 2) where ``velocity`` has no
    rows) of the k boxes whose code is not negative, in their order."""
    n = codes.shape[0]
    k = 0
    for i in range(n):
        if codes[i] >= 0:
            k += 1
    params = np.empty((k, 7))
    out_score = np.empty(k)
    out_codes = np.empty(k, np.int32)
    out_velocity = np.empty((k if velocity.shape[0] else 0, 2))
    j = 0
    for i in range(n):
        if codes[i] < 0:
            continue
        params[j, X] = center[i, 0]
        params[j, Y] = center[i, 1]
        params[j, Z] = center[i, 2]
        params[j, YAW] = yaw[i]
        params[j, L] = size[i, 0]
        params[j, W] = size[i, 1]
        params[j, H] = size[i, 2]
        out_score[j] = score[i]
        out_codes[j] = codes[i]
        if velocity.shape[0]:
            out_velocity[j, 0] = velocity[i, 0]
            out_velocity[j, 1] = velocity[i, 1]
        j += 1
    return params, out_score, out_codes, out_velocity
