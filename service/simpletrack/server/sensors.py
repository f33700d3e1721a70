"""Per-sensor state and the rules a frame's ``seq`` and ``stamp_ns`` must follow against the
last frame the sensor tracked. Pure: no Zenoh, no threads, no metrics; the worker applies the
verdict (docs/SERVICE.md, "Per-sensor order").
"""

from __future__ import annotations

import threading
import time
from collections import deque
from dataclasses import dataclass, field
from enum import Enum

from simpletrack.core.state import TrackTable
from simpletrack.core.tracker import Tracker
from simpletrack.server.checkpoint_rule import CheckpointMark
from simpletrack.wire.decoding import Rejection
from simpletrack.wire.messages import DetectionFrame
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


@dataclass(frozen=True, slots=True)
class Arrival:
    """What the ordering rules read of a frame: its ``seq`` and sensor ``stamp_ns``, the
    service's wall clock at receipt (None: unknown, e.g. a snapshot of before the field) and
    the publisher's ``session_id`` (None: the publisher sends none)."""

    seq: int
    stamp_ns: int
    received_ns: int | None = None
    session_id: int | None = None


@dataclass(slots=True)  # not frozen: one is made per frame, and frozen sets each field by a call
class _Undo:
    """A sensor as it was before its last frame. Cheap: the tracker replaces its track
    table on every step and never writes into it, so holding the old one copies nothing."""

    tracks: TrackTable
    frame_count: int
    tracker_last_stamp: float | None
    id_base: int
    stamp_origin_ns: int | None
    last: Arrival | None
    active_tracks: int


RATE_WINDOW_S = 10.0  # the status's rate_hz: frames tracked over this window
RATE_FRAMES = 1024  # at most this many kept for it (over 100 Hz the window shrinks)


@dataclass
class SensorState:
    vehicle: str
    sensor: str
    tracker: Tracker
    id_base: int = 0  # wire id = id_base + tracker id; raised past every id on each reset
    last: Arrival | None = None  # the last tracked frame
    before: Arrival | None = None  # the one tracked before it (None after a restore or undo)
    stamp_origin_ns: int | None = None
    frames: int = 0
    active_tracks: int = 0
    last_seen: float = field(default_factory=time.monotonic)
    dirty: bool = True
    # (standby, frames) of the last checkpoint sent: unchanged, nothing to send
    checkpoint_mark: CheckpointMark | None = None
    _undo: _Undo | None = None
    epoch: int = 0  # custody epoch (docs/SCALE.md, "Fencing"): on every tracks message
    resets: int = 0  # on this instance (the status's, not kept in snapshots)
    implausible: int = 0  # frames tracked with a plausibility warning, on this instance
    tracked_at: deque[float] = field(default_factory=lambda: deque(maxlen=RATE_FRAMES))

    @property
    def id_next(self) -> int:
        return self.id_base + self.tracker.next_id

    @property
    def last_seq(self) -> int | None:
        return None if self.last is None else self.last.seq

    @property
    def last_stamp_ns(self) -> int | None:
        return None if self.last is None else self.last.stamp_ns

    def keep_undo(self) -> None:
        """Remember the sensor as it is, before a frame changes it (see ``undo_last``)."""
        t = self.tracker
        self._undo = _Undo(
            t.tracks,
            t.frame_count,
            t.last_stamp,
            self.id_base,
            self.stamp_origin_ns,
            self.last,
            self.active_tracks,
        )

    def undo_last(self) -> int:
        """Put the sensor back as it was before its last frame (a frame the wall clock
        says was wrong); returns the change in active tracks. Ids born on the undone frame
        stay used: the tracker's next id is kept past them."""
        u = self._undo
        if u is None:
            raise RuntimeError("nothing to undo")
        id_next = self.id_next
        t = self.tracker
        t.tracks, t.frame_count, t.last_stamp = u.tracks, u.frame_count, u.tracker_last_stamp
        self.id_base, self.stamp_origin_ns, self.last = u.id_base, u.stamp_origin_ns, u.last
        t.next_id = max(t.next_id, id_next - self.id_base)
        self.before = self._undo = None
        delta = u.active_tracks - self.active_tracks
        self.active_tracks = u.active_tracks
        self.dirty = True
        return delta

    def reset(self, stamp_ns: int) -> None:
        """A fresh tracker whose time starts at ``stamp_ns`` and whose ids start above every
        id published so far. The last frame is kept: the undo rule may still need it."""
        self.id_base = self.id_next
        self.tracker.reset()
        self.stamp_origin_ns = stamp_ns
        self.active_tracks = 0
        self.resets += 1

    def tracker_stamp(self, stamp_ns: int) -> float:
        """The tracker's time of a frame: seconds since the first frame (or the last reset)."""
        if self.stamp_origin_ns is None:
            self.stamp_origin_ns = stamp_ns
        return (stamp_ns - self.stamp_origin_ns) * 1e-9

    def tracked(self, frame: Arrival, active_tracks: int) -> int:
        """Record a tracked frame; returns the change in active tracks."""
        delta = active_tracks - self.active_tracks
        self.active_tracks = active_tracks
        self.before, self.last = self.last, frame
        self.frames += 1
        self.dirty = True
        self.tracked_at.append(time.monotonic())
        return delta

    def rate_hz(self, now: float) -> float:
        """Frames tracked per second over the last ``RATE_WINDOW_S`` (0 when fewer than two):
        falls to 0 within the window once the sensor stops."""
        recent = [t for t in tuple(self.tracked_at) if now - t <= RATE_WINDOW_S]
        if len(recent) < 2:
            return 0.0
        return (len(recent) - 1) / max(recent[-1] - recent[0], 1e-9)

    def snapshot(
        self, digest: str, with_tracker: bool = True, *, state_format: int
    ) -> SensorSnapshot:
        """``state_format``: the tracker's byte form (``core.tracker.STATE_FORMATS``)."""
        last = self.last
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
            last_received_ns=None if last is None else last.received_ns,
            last_session_id=None if last is None else last.session_id,
            config_digest=digest,
            tracker=self.tracker.to_bytes(state_format) if with_tracker else None,
            written_ns=time.time_ns(),
            epoch=self.epoch,
        )


# ---------------------------------------------------------------------------- ordering rules
class Order(Enum):
    """What to do with a frame of a sensor the service already holds."""

    TRACK = "track"
    BRIDGE_GAP = "outage"  # a stamp gap the service's clock saw too: track across it
    UNDO_LAST = "undo"  # the last frame disagreed with the wall clock, this one agrees
    RESET_GAP = "gap"  # value: the ``reason`` label of simpletrack_tracker_resets_total
    RESET_TIME_BACKWARDS = "time_backwards"
    RESET_RESTART = "restart"  # a new publisher session whose stamps start at or before ours
    DUPLICATE_SEQ = "duplicate_seq"
    OUT_OF_ORDER = "out_of_order"

    @property
    def resets(self) -> bool:
        return self in RESETS

    @property
    def tracks(self) -> bool:
        return self in (Order.TRACK, Order.BRIDGE_GAP)


RESETS = frozenset({Order.RESET_GAP, Order.RESET_TIME_BACKWARDS, Order.RESET_RESTART})


# How far a sensor's clock may be from the service's and still agree with it: synchronised
# clocks (NTP, PTP) agree to milliseconds and delivery adds tens; a second is neither. The one
# figure of the undo rule (below) and of the ``stamp_offset`` warning and the clock metrics
# (plausibility.py, metrics.py). A fused vehicle judges its sensors' clocks more tightly,
# against each other: its ``fusion.clock_tolerance_s`` (0.1 s by default).
CLOCK_TOLERANCE_S = 1.0


@dataclass(frozen=True, slots=True)
class OrderRules:
    reset_gap_s: float  # a stamp step this far ahead of the service's clock resets
    reset_backward_s: float  # a stamp further behind than this resets it (less: refused)
    # How far a frame's stamp step may differ from the service's clock step and still count
    # as agreeing with it (network jitter, bursts): only the undo rule reads it.
    clock_tolerance_s: float = CLOCK_TOLERANCE_S


@dataclass(frozen=True, slots=True)
class Verdict:
    """The ordering decision; a refusal also carries its wire reason, field and detail."""

    order: Order
    reason: ErrorReason | None = None
    field: str | None = None
    detail: str = ""


TRACK = Verdict(Order.TRACK)


def lead_ns(ref: Arrival, frame: Arrival) -> int | None:
    """How much further the sensor's clock moved from ``ref`` to ``frame`` than the
    service's did; None when a receipt time is unknown. About 0 for a live stream, also
    across an outage; a sensor clock jump shows as the jump."""
    if ref.received_ns is None or frame.received_ns is None:
        return None
    return (frame.stamp_ns - ref.stamp_ns) - (frame.received_ns - ref.received_ns)


def key_mismatch(frame: DetectionFrame, vehicle: str, sensor: str) -> Rejection | None:
    """The refusal of a frame whose payload names another vehicle or sensor than its key."""
    if frame.vehicle == vehicle and frame.sensor == sensor:
        return None
    field_name = "vehicle" if frame.vehicle != vehicle else "sensor"
    detail = f"payload says {frame.vehicle}/{frame.sensor}, key says {vehicle}/{sensor}"
    return Rejection(ErrorReason.KEY_MISMATCH, field_name, detail, frame.seq, frame.stamp_ns)


def check_order(
    last: Arrival | None, frame: Arrival, rules: OrderRules, before: Arrival | None = None
) -> Verdict:
    """Judge a frame against the sensor's last tracked one (and the one ``before`` it, for
    the undo rule). ``seq`` orders nothing: only an exact repeat is refused for it, so no
    seq a frame carries, spoofed or restarted, can make later frames fail."""
    if last is None:
        return TRACK
    verdict = _against_last(last, frame, rules)
    if before is None:
        return verdict
    # A frame of another session between two of one stream is undone even when it reset
    # nothing; any other last frame only when this one could not follow it.
    stray = last.session_id != before.session_id == frame.session_id
    if (stray or not verdict.order.tracks) and _last_was_wrong(before, last, frame, rules):
        return Verdict(Order.UNDO_LAST)
    return verdict


def unheard_start(last: Arrival | None, frame: Arrival) -> bool:
    """``frame`` is the first heard of a publisher session that published before it: another
    session than the sensor's last frame's, later, and its seq neither 0 (a new numbering's
    first) nor the one after the last (a publisher that resumed). Its earlier frames reached
    nobody here (a vehicle rebooted while its router was away); its cache may keep them."""
    return (
        last is not None
        and frame.session_id is not None
        and last.session_id is not None
        and frame.session_id != last.session_id
        and frame.stamp_ns > last.stamp_ns
        and frame.seq not in (0, last.seq + 1)
    )


def _against_last(last: Arrival, frame: Arrival, rules: OrderRules) -> Verdict:
    ahead = frame.stamp_ns - last.stamp_ns
    if frame.session_id != last.session_id:  # a restarted publisher: its seq starts afresh
        return _forward(last, frame, rules) if ahead > 0 else Verdict(Order.RESET_RESTART)
    if frame.seq == last.seq and ahead <= 0:
        return Verdict(
            Order.DUPLICATE_SEQ,
            ErrorReason.DUPLICATE_SEQ,
            "seq",
            f"seq {frame.seq} was already processed",
        )
    if -ahead > rules.reset_backward_s * 1e9:
        return Verdict(Order.RESET_TIME_BACKWARDS)
    if ahead <= 0:
        return Verdict(
            Order.OUT_OF_ORDER,
            ErrorReason.OUT_OF_ORDER,
            "stamp_ns",
            f"stamp_ns {frame.stamp_ns} is not after the last processed {last.stamp_ns}",
        )
    return _forward(last, frame, rules)


def _forward(last: Arrival, frame: Arrival, rules: OrderRules) -> Verdict:
    gap = rules.reset_gap_s * 1e9
    if frame.stamp_ns - last.stamp_ns <= gap:
        return TRACK
    lead = lead_ns(last, frame)
    if lead is not None and lead <= gap:  # the service was away as long: an outage
        return Verdict(Order.BRIDGE_GAP)
    return Verdict(Order.RESET_GAP)


def _last_was_wrong(before: Arrival, last: Arrival, frame: Arrival, rules: OrderRules) -> bool:
    """The last frame is to be undone when this one, of the stream before it, agrees with
    the service's clock and the last one did not, or came from another session: one bad
    frame then costs itself, never the frames after it."""
    if frame.session_id != before.session_id or frame.stamp_ns <= before.stamp_ns:
        return False
    lead_frame, lead_last = lead_ns(before, frame), lead_ns(before, last)
    if lead_frame is None or lead_last is None:
        return False
    tol = rules.clock_tolerance_s * 1e9
    if abs(lead_frame) > tol:
        return False
    return last.session_id != before.session_id or abs(lead_last) > tol
