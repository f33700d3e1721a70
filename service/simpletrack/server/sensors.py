"""Per-sensor state and the rules a frame's ``seq`` and ``stamp_ns`` must follow against the
last frame the sensor tracked. Pure: no Zenoh, no threads, no metrics; the worker applies the
verdict (docs/SERVICE.md, "Per-sensor order").
"""

from __future__ import annotations

import threading
import time
from dataclasses import dataclass, field
from enum import Enum

from simpletrack.core.tracker import Tracker
from simpletrack.wire.models import SensorSnapshot
from simpletrack.wire.reasons import SCHEMA_VERSION, ErrorReason


class SensorBudget:
    """Caps the sensors held in memory across all workers."""

    def __init__(self, limit: int) -> None:
        self.limit, self.used = limit, 0
        self._lock = threading.Lock()

    def acquire(self) -> bool:
        with self._lock:
            if self.used >= self.limit:
                return False
            self.used += 1
            return True

    def release(self) -> None:
        with self._lock:
            self.used -= 1


@dataclass
class SensorState:
    vehicle: str
    sensor: str
    tracker: Tracker
    id_base: int = 0  # wire id = id_base + tracker id; raised past every id on each reset
    last_seq: int | None = None
    last_stamp_ns: int | None = None
    stamp_origin_ns: int | None = None
    frames: int = 0
    active_tracks: int = 0
    last_seen: float = field(default_factory=time.monotonic)
    dirty: bool = True

    @property
    def id_next(self) -> int:
        return self.id_base + self.tracker.next_id

    def reset(self, stamp_ns: int) -> None:
        """A fresh tracker whose time starts at ``stamp_ns`` and whose ids start above every
        id published so far; the next frame is checked against nothing."""
        self.id_base = self.id_next
        self.tracker.reset()
        self.stamp_origin_ns = stamp_ns
        self.last_seq = self.last_stamp_ns = None
        self.active_tracks = 0

    def tracker_stamp(self, stamp_ns: int) -> float:
        """The tracker's time of a frame: seconds since the first frame (or the last reset)."""
        if self.stamp_origin_ns is None:
            self.stamp_origin_ns = stamp_ns
        return (stamp_ns - self.stamp_origin_ns) * 1e-9

    def tracked(self, seq: int, stamp_ns: int, active_tracks: int) -> int:
        """Record a tracked frame; returns the change in active tracks."""
        delta = active_tracks - self.active_tracks
        self.active_tracks = active_tracks
        self.last_seq, self.last_stamp_ns = seq, stamp_ns
        self.frames += 1
        self.dirty = True
        return delta

    def snapshot(self, digest: str, with_tracker: bool = True) -> SensorSnapshot:
        return SensorSnapshot(
            schema_version=SCHEMA_VERSION,
            vehicle=self.vehicle,
            sensor=self.sensor,
            last_seq=self.last_seq,
            last_stamp_ns=self.last_stamp_ns,
            stamp_origin_ns=self.stamp_origin_ns,
            id_base=self.id_base if with_tracker else self.id_next,
            id_next=self.id_next,
            frames=self.frames,
            config_digest=digest,
            tracker=self.tracker.to_bytes() if with_tracker else None,
            written_ns=time.time_ns(),
        )


# ---------------------------------------------------------------------------- ordering rules
class Order(Enum):
    """What to do with a frame of a sensor the service already holds."""

    TRACK = "track"
    RESET_GAP = "gap"  # value: the ``reason`` label of simpletrack_tracker_resets_total
    RESET_TIME_BACKWARDS = "time_backwards"
    DUPLICATE_SEQ = "duplicate_seq"
    OUT_OF_ORDER = "out_of_order"
    SEQ_NOT_INCREASING = "seq_not_increasing"

    @property
    def resets(self) -> bool:
        return self in (Order.RESET_GAP, Order.RESET_TIME_BACKWARDS)


@dataclass(frozen=True, slots=True)
class OrderRules:
    reset_gap_s: float  # a stamp further ahead than this resets the tracker
    reset_backward_s: float  # a stamp further behind than this resets it (less: refused)


@dataclass(frozen=True, slots=True)
class Verdict:
    """The ordering decision; a refusal also carries its wire reason, field and detail."""

    order: Order
    reason: ErrorReason | None = None
    field: str | None = None
    detail: str = ""


TRACK = Verdict(Order.TRACK)


def check_order(
    last_seq: int | None, last_stamp_ns: int | None, seq: int, stamp_ns: int, rules: OrderRules
) -> Verdict:
    """Judge a frame against the sensor's last tracked one. The checks run in this order, so
    that e.g. a replay restarted (seq and stamp both back) resets rather than being refused."""
    if last_seq is None or last_stamp_ns is None:
        return TRACK
    if seq == last_seq:
        return Verdict(
            Order.DUPLICATE_SEQ,
            ErrorReason.DUPLICATE_SEQ,
            "seq",
            f"seq {seq} was already processed",
        )
    behind = last_stamp_ns - stamp_ns
    if behind > rules.reset_backward_s * 1e9:
        return Verdict(Order.RESET_TIME_BACKWARDS)
    if behind >= 0:
        return Verdict(
            Order.OUT_OF_ORDER,
            ErrorReason.OUT_OF_ORDER,
            "stamp_ns",
            f"stamp_ns {stamp_ns} is not after the last processed {last_stamp_ns}",
        )
    if seq < last_seq:
        return Verdict(
            Order.SEQ_NOT_INCREASING,
            ErrorReason.SEQ_NOT_INCREASING,
            "seq",
            f"seq {seq} is below the last processed {last_seq}",
        )
    if -behind > rules.reset_gap_s * 1e9:
        return Verdict(Order.RESET_GAP)
    return TRACK
