"""Plausibility of a decoded detection frame: values the decoder accepts (they are within its
hard bounds, schemas/README.md "Bounds") but that look like a unit or convention mistake
upstream — millimetres, degrees, logits, stamps in seconds. Nothing here refuses a frame:
the worker counts and logs what is found and tracks the frame exactly as before.

Pure: numpy only, a few reductions per frame (docs/SERVICE.md, "Plausibility warnings").
The thresholds are chosen against real detections: no frame of the KITTI PointRCNN or
nuScenes CenterPoint data trips any of them (tests/server/test_plausibility.py).
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from enum import StrEnum

import numpy as np
import numpy.typing as npt

from simpletrack.core.config import TrackerConfig
from simpletrack.server.sensors import CLOCK_TOLERANCE_S
from simpletrack.wire.columns import I32, BoxArrays

F64 = npt.NDArray[np.float64]

# Longest side of a box, median over the frame. Real frames peak at 5.2 m (nuScenes, 10k
# frames) and a single box at 26.6 m (a trailer); the longest road vehicles (road trains,
# articulated trams) stay under this. Millimetres and centimetres never get here: any side
# over 100 m is refused by the decoder; what is left is decimetres, or a column mix-up.
MAX_MEDIAN_SIZE_M = 30.0
# How far apart two boxes of one frame can be, and how far from the sensor a box can be when
# the frame has a pose (boxes then are in the sensor's frame). Lidar and radar see ~300 m;
# real frames span at most 109 m. A frame in millimetres spans tens of kilometres.
MAX_SPAN_M = 2000.0
# Any |yaw| over this. Real yaws stay within ±π; a converter that shifts a [0, 2π) heading by
# a quarter turn (camera rot_y to lidar yaw) legitimately reaches 2.5π. Degrees go past it
# in nearly every frame with a few boxes (any heading over 7.9°).
MAX_YAW_RAD = 2.5 * math.pi
# A frame whose boxes can start no track at all is only suspicious when it has many boxes:
# KITTI's PointRCNN frames in which no box reaches its class's score_high have at most 6.
MIN_BOXES_UNDER_THRESHOLD = 16
# Sensor stamp against the service's clock at receipt: further apart than CLOCK_TOLERANCE_S
# (server/sensors.py, 1 s) is a wrong unit, a wrong clock or a replay. A frame stamped ahead
# is one at once (nothing arrives before it is captured); one stamped behind only when its
# sensor's least delay lately is (LeastLag): a single late frame is a delivery's, not a clock's.
_DAY_NS = 86_400 * 10**9  # a stamp read in another unit lands this close to the receipt
# LeastLag's window: a clock stepped back is relearned within two of them.
CLOCK_WINDOW_NS = 10 * 10**9


class Cause(StrEnum):
    """What looks wrong; the ``cause`` label of ``simpletrack_implausible_frames_total``."""

    SIZE_UNIT = "size_unit"
    CENTER_UNIT = "center_unit"
    YAW_DEGREES = "yaw_degrees"
    SCORE_RANGE = "score_range"
    SCORE_UNDER_THRESHOLD = "score_under_threshold"
    STAMP_SECONDS = "stamp_seconds"
    STAMP_MILLISECONDS = "stamp_milliseconds"
    STAMP_MICROSECONDS = "stamp_microseconds"
    STAMP_OFFSET = "stamp_offset"


@dataclass(frozen=True, slots=True)
class Finding:
    cause: Cause
    hint: str  # the likely cause, for the log line
    value: float  # the figure the hint quotes


class LeastLag:
    """A sensor's least ``received_ns - stamp_ns`` over its frames of the last 10 to 20 s
    (two windows of ``CLOCK_WINDOW_NS``; the older is dropped as a new one opens): delivery
    only ever adds to a frame's, so the least is the sensor's clock offset plus its fastest
    delivery, the standard estimate of the offset. Negative: the sensor's stamps run ahead of
    the service's clock by at least that much. Two integers a frame; times are receipts."""

    __slots__ = ("_cur", "_prev", "_until", "last_ns")

    def __init__(self) -> None:
        self._cur: int | None = None  # the least of the window open now
        self._prev: int | None = None  # the least of the window before it (None: no frame)
        self._until = 0  # when the open window closes
        self.last_ns = 0  # receipt of the last frame seen

    def see(self, stamp_ns: int, received_ns: int) -> int:
        """Take a frame in; its sensor's least delay now, this frame included."""
        lag, w = received_ns - stamp_ns, CLOCK_WINDOW_NS
        if self._cur is None or received_ns < self._until - 2 * w:  # first, or clock set back
            self._cur, self._prev, self._until = lag, None, received_ns + w
        elif received_ns >= self._until:
            self._prev = self._cur if received_ns < self._until + w else None
            self._cur, self._until = lag, received_ns + w
        elif lag < self._cur:
            self._cur = lag
        self.last_ns = received_ns
        return self.least

    @property
    def least(self) -> int:
        """ns; 0 before any frame."""
        cur = 0 if self._cur is None else self._cur
        return cur if self._prev is None else min(cur, self._prev)

    def fresh(self, now_ns: int) -> bool:
        """A frame was seen within the last two windows (the least speaks of now)."""
        return self._cur is not None and now_ns - self.last_ns <= 2 * CLOCK_WINDOW_NS


@dataclass(frozen=True, slots=True)
class StartThresholds:
    """The score a box needs to start a track (stage 1, ``score >= score_high``): per tracker
    class code on key frames, one for every class on non-key frames."""

    key: F64
    non_key: float
    # Indexed by a box's code, -1 (an ignored class) reaching the last entry, inf: one lookup
    # gives each box its threshold, none an ignored box reaches.
    by_code: F64 = field(init=False, repr=False)
    non_key_by_code: F64 = field(init=False, repr=False)

    def __post_init__(self) -> None:
        n = len(self.key)
        object.__setattr__(self, "by_code", np.append(self.key.astype(np.float64), np.inf))
        object.__setattr__(
            self, "non_key_by_code", np.append(np.full(n, float(self.non_key)), np.inf)
        )

    @classmethod
    def of(cls, config: TrackerConfig) -> StartThresholds:
        key = [config.for_code(c).score_high for c in range(len(config.classes))]
        return cls(np.array(key, dtype=np.float64), config.non_key.score_high)


def check_frame(
    boxes: BoxArrays,
    stamp_ns: int,
    received_ns: int,
    *,
    has_pose: bool = False,
    codes: I32 | None = None,
    thresholds: StartThresholds | None = None,
    key_frame: bool = True,
    least_lag_ns: int | None = None,
    extents: Mapping[str, tuple[float, float]] | None = None,
) -> list[Finding]:
    """Every implausibility of one frame (empty: nothing looks wrong). ``codes`` are the
    boxes' tracker class codes (-1: ignored class), needed with ``thresholds``;
    ``least_lag_ns`` its sensor's least delay lately (``LeastLag``; None: this frame's own);
    ``extents`` the least and greatest value of each column (the decoder's,
    ``DecodedDetections.extents``; None: reduced here)."""
    found = _stamp(stamp_ns, received_ns, least_lag_ns)
    if not len(boxes):
        return found
    if extents is None:
        extents = _extents(boxes)
    # The median (a sort) and the span only when one plain reduction says they could trip.
    longest = 0.0
    if extents["size"][1] > MAX_MEDIAN_SIZE_M:
        longest = float(np.median(boxes.size.max(axis=1)))
    if longest > MAX_MEDIAN_SIZE_M:
        found.append(
            Finding(
                Cause.SIZE_UNIT,
                f"sizes look like another unit than metres, decimetres? (median longest side "
                f"{longest:.1f}; road objects measure 0.2 to 25 m)",
                longest,
            )
        )
    xy = boxes.center[:, :2]
    # |x|, |y| and |z| within half the span: no centre is further out in x or y.
    lo, hi = extents["center"]
    far = max(-lo, hi)
    if far > MAX_SPAN_M / 2:
        far = float(np.abs(xy).max())
    span = float((xy.max(axis=0) - xy.min(axis=0)).max()) if far > MAX_SPAN_M / 2 else 0.0
    far = far if has_pose else 0.0
    if max(span, far) > MAX_SPAN_M:
        what = f"boxes span {span:.0f}" if span >= far else f"a box is {far:.0f} from the sensor"
        found.append(
            Finding(
                Cause.CENTER_UNIT,
                f"centres look like millimetres ({what}; no sensor sees beyond ~300 m)",
                max(span, far),
            )
        )
    lo, hi = extents["yaw"]
    yaw = max(-lo, hi)
    if yaw > MAX_YAW_RAD:
        found.append(
            Finding(
                Cause.YAW_DEGREES, f"yaw looks like degrees (max |yaw| {yaw:.1f}; radians)", yaw
            )
        )
    found += _scores(boxes, extents["score"], codes, thresholds, key_frame)
    return found


def _extents(boxes: BoxArrays) -> dict[str, tuple[float, float]]:
    """What check_frame reads of each column: its least and greatest value."""
    return {
        name: (float(values.min()), float(values.max()))
        for name, values in (
            ("center", boxes.center),
            ("size", boxes.size),
            ("yaw", boxes.yaw),
            ("score", boxes.score),
        )
    }


def _scores(
    boxes: BoxArrays,
    extent: tuple[float, float],
    codes: I32 | None,
    thresholds: StartThresholds | None,
    key_frame: bool,
) -> list[Finding]:
    lo, hi = extent
    found = []
    if lo < 0.0 or hi > 1.0:
        # Only logits go negative; over 1 and never negative may be percentages too.
        figure, which, like = (
            (lo, "min", "logits") if lo < 0.0 else (hi, "max", "logits or percentages")
        )
        found.append(
            Finding(
                Cause.SCORE_RANGE,
                f"scores look like {like} ({which} {figure:g}); scores are probabilities in [0, 1]",
                figure,
            )
        )
    if codes is None or thresholds is None:
        return found
    # A box that can start a track settles it, the usual case: three numpy calls.
    need = (thresholds.by_code if key_frame else thresholds.non_key_by_code)[codes]
    if (boxes.score >= need).any():
        return found
    tracked = codes >= 0
    n = int(tracked.sum())
    if n >= MIN_BOXES_UNDER_THRESHOLD:
        score = boxes.score[tracked]
        lowest = float(need[tracked].min())
        found.append(
            Finding(
                Cause.SCORE_UNDER_THRESHOLD,
                f"every score is under the tracker's lowest threshold {lowest:g} (max score "
                f"{float(score.max()):g} of {n} boxes): no track can start",
                float(score.max()),
            )
        )
    return found


def _stamp(stamp_ns: int, received_ns: int, least_lag_ns: int | None) -> list[Finding]:
    lag_ns = received_ns - stamp_ns
    if abs(lag_ns) <= CLOCK_TOLERANCE_S * 1e9:
        return []
    # Read as another unit, does the stamp land within a day of the receipt? Then that unit
    # is the likely one (a day: clocks that are off as well still read as the unit).
    for cause, unit, scale in (
        (Cause.STAMP_SECONDS, "seconds", 10**9),
        (Cause.STAMP_MILLISECONDS, "milliseconds", 10**6),
        (Cause.STAMP_MICROSECONDS, "microseconds", 10**3),
    ):
        if abs(stamp_ns * scale - received_ns) < _DAY_NS:
            hint = f"stamp looks like {unit} (stamp_ns {stamp_ns}); stamp_ns is nanoseconds"
            return [Finding(cause, hint, float(stamp_ns))]
    if lag_ns > 0 and least_lag_ns is not None:
        lag_ns = min(lag_ns, least_lag_ns)  # behind: by the sensor's least delay lately
        if lag_ns <= CLOCK_TOLERANCE_S * 1e9:
            return []  # a late frame (a recovered one, a stall): its sensor's others were not
    offset_s = lag_ns * 1e-9
    ahead = "behind" if offset_s > 0 else "ahead of"
    size = f"{abs(offset_s):.1f}" if abs(offset_s) < 100 else f"{abs(offset_s):.0f}"
    hint = (
        f"the vehicle's clock is {size} s {ahead} the service's, or this is a "
        f"replay (stamps since boot count too)"
    )
    return [Finding(Cause.STAMP_OFFSET, hint, offset_s)]


__all__ = ["Cause", "Finding", "LeastLag", "StartThresholds", "check_frame"]
