"""The last check before a track frame leaves: finite floats only; and numpy's floating-point
errors of a frame's arithmetic, collected for the event log.

Detections within the wire's bounds (schemas/README.md, "Bounds") cannot drive the tracker
out of float32; this guard is what holds the promise should that ever be wrong: a subscriber's
decoder refuses a non-finite track frame, so publishing one would lose every track of it.
"""

from __future__ import annotations

import math
from types import TracebackType

import numpy as np

from simpletrack.wire.codec import Rejection
from simpletrack.wire.columns import VEHICLE_TRACK_COLUMNS, TrackArrays
from simpletrack.wire.reasons import ErrorReason

# A vehicle's columns are a sensor's and ``existence``: absent (None) in a sensor's tracks.
FLOAT_COLUMNS = tuple(c.name for c in VEHICLE_TRACK_COLUMNS if c.finite)
_sum = np.add.reduce  # ndarray.sum without its Python wrapper (eight columns a frame)


def first_non_finite(tracks: TrackArrays) -> tuple[str, int] | None:
    """The first float column (table order) holding NaN or inf, and the row; None if none."""
    with np.errstate(over="ignore", invalid="ignore"):  # the sums' own: nothing to report
        for name in FLOAT_COLUMNS:
            values = getattr(tracks, name)
            if values is None:  # an optional column not sent (e.g. no covariance)
                continue
            # One reduction per column: a NaN or inf makes the sum NaN or inf. A sum of
            # finite values that overflows only sends the column to the exact look below.
            if math.isfinite(_sum(values, axis=None)):
                continue
            bad = ~np.isfinite(values)
            if bad.any():
                return name, int(np.argwhere(bad)[0][0])
    return None


def non_finite_refusal(tracks: TrackArrays, seq: int, stamp_ns: int) -> Rejection | None:
    """The refusal of a track frame that must not be published, or None when it may be."""
    bad = first_non_finite(tracks)
    if bad is None:
        return None
    column, row = bad
    return Rejection(
        ErrorReason.INTERNAL_ERROR,
        f"tracks.{column}",
        f"the tracker produced NaN or inf in tracks.{column} row {row}; the frame was not "
        "published and the tracker that produced it was reset",
        seq,
        stamp_ns,
    )


class FloatingPointErrors:
    """Records numpy's floating-point errors (overflow, invalid value, divide by zero) raised
    inside ``with`` blocks instead of letting numpy print a RuntimeWarning to stderr, outside
    the event log. Results are unchanged: numpy carries on as with its default ``warn``.

    ``np.errstate`` lives in a context variable, so each worker thread has its own."""

    def __init__(self) -> None:
        self.kinds: list[str] = []  # first-seen order, each once
        self._active: list[np.errstate] = []

    def _seen(self, kind: str, _flag: int) -> None:
        if kind not in self.kinds:
            self.kinds.append(kind)

    def __enter__(self) -> FloatingPointErrors:
        # An errstate can be entered once only: a fresh one per block.
        state = np.errstate(divide="call", over="call", invalid="call", call=self._seen)
        state.__enter__()
        self._active.append(state)
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        self._active.pop().__exit__(exc_type, exc, tb)


__all__ = ["FLOAT_COLUMNS", "FloatingPointErrors", "first_non_finite", "non_finite_refusal"]
