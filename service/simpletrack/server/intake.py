"""From Zenoh to the workers: the subscriber callback and each worker's bounded, fair queue.

The callback does no decoding and no tracking: it copies the payload out of Zenoh, stamps
the receipt time and appends to the queue of the worker that owns the key (a sensor always
maps to the same worker, which keeps its frames in order).

Inside a worker's queue every key has its own lane and the worker serves the lanes in turn
(round robin), with the snapshot queries as one more lane: a sensor that floods, or a flood
of queries, waits behind itself, never in front of its neighbours (docs/SERVICE.md, "What a
fault can cost").
"""

from __future__ import annotations

import threading
import time
import zlib
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass, field
from enum import Enum

import zenoh

from simpletrack.server.settings import Backpressure
from simpletrack.wire.header import peek_header
from simpletrack.wire.messages import MAX_NOTICE_SEQS
from simpletrack.wire.reasons import ErrorReason

# Snapshot queries waiting per worker; more are refused at once (the querier gets an error).
MAX_QUERIES = 16
_CONTROL = ""  # the queries' place in the rotation: no Zenoh key is empty


class Kind(Enum):
    DETECTIONS = "detections"
    CHECKPOINT = "checkpoint"  # another member's state of a sensor this one stands by for


@dataclass(frozen=True, slots=True)
class Inbound:
    """A payload as received: its key, bytes, and when it arrived."""

    key: str
    payload: bytes
    received_ns: int  # wall clock (unix ns): goes on the wire
    received_at: float  # time.perf_counter(): measures the queue wait
    kind: Kind = Kind.DETECTIONS


def stamp_of(item: Inbound) -> int | None:
    """The frame's ``stamp_ns`` from its header alone (None: unreadable)."""
    return peek_header(item.payload)[1]


@dataclass(slots=True)
class Dropped:
    """Frames of one key the queue had to give up, announced by the worker in one notice."""

    key: str
    reason: ErrorReason
    seqs: list[int | None]  # None: the frame's seq could not be read
    stamp_ns: int | None  # of the first frame
    received_ns: int  # when the first frame arrived


@dataclass(slots=True)
class _Lane:
    frames: deque[Inbound] = field(default_factory=deque)
    drops: deque[Dropped] = field(default_factory=deque)


class WorkQueue:
    """The frames waiting for one worker, at most ``maxsize`` in all, in one lane per key;
    the drop notices of each lane; and a bounded lane of control callables (queries).
    ``get`` serves the lanes in turn, one item per turn."""

    def __init__(self, maxsize: int, max_control: int = MAX_QUERIES) -> None:
        self.maxsize, self.max_control = maxsize, max_control
        self._lanes: dict[str, _Lane] = {}  # keys with frames or notices waiting
        self._ring: deque[str] = deque()  # the keys of _lanes (and _CONTROL) in serving order
        self._control: deque[Callable[[], None]] = deque()
        self._frames = 0
        self._busy = 0  # lanes holding frames
        self._cond = threading.Condition()
        self._closed = False

    def __len__(self) -> int:
        return self._frames

    @property
    def closed(self) -> bool:
        return self._closed

    def _lane(self, key: str) -> _Lane:
        lane = self._lanes.get(key)
        if lane is None:
            lane = self._lanes[key] = _Lane()
            self._ring.append(key)
        return lane

    def _append(self, item: Inbound) -> None:
        lane = self._lane(item.key)
        if not lane.frames:
            self._busy += 1
        lane.frames.append(item)
        self._frames += 1

    def _pop_frame(self, lane: _Lane) -> Inbound:
        item = lane.frames.popleft()
        self._frames -= 1
        if not lane.frames:
            self._busy -= 1
        return item

    def _victim(self, arriving: str) -> _Lane:
        """The lane that gives up its oldest frame when the queue is full: the arriving
        key's own when it holds at least an equal share, else the one holding the most."""
        own = self._lanes.get(arriving)
        if own is not None and len(own.frames) * self._busy >= self._frames:
            return own
        return max((lane for lane in self._lanes.values() if lane.frames), key=_depth)

    def put_drop_oldest(self, item: Inbound) -> tuple[bool, Inbound | None]:
        """Enqueue; a full queue gives up the oldest frame of its fullest lane, returned (its
        notice is queued for the worker to publish). ``(False, None)`` if closed."""
        with self._cond:
            if self._closed:
                return False, None
            evicted = None
            if self._frames >= self.maxsize:
                evicted = self._pop_frame(self._victim(item.key))
            self._append(item)
            self._cond.notify()
        if evicted is not None:
            # Only the header is read, and outside the lock: the worker keeps going meanwhile.
            self.note_drop(evicted, ErrorReason.DROPPED_QUEUE_FULL, *peek_header(evicted.payload))
        return True, evicted

    def note_drop(
        self, item: Inbound, reason: ErrorReason, seq: int | None, stamp_ns: int | None
    ) -> None:
        """Add a given-up frame to its key's pending notice (a new one when the last is full
        or has another reason). Never refused, never discarded: every drop is announced."""
        with self._cond:
            drops = self._lane(item.key).drops
            last = drops[-1] if drops else None
            if last is None or last.reason is not reason or len(last.seqs) >= MAX_NOTICE_SEQS:
                drops.append(Dropped(item.key, reason, [seq], stamp_ns, item.received_ns))
            else:
                last.seqs.append(seq)
            self._cond.notify()

    def put_blocking(self, item: Inbound) -> bool:
        """Enqueue, waiting for room (pushes back on Zenoh). False if the queue is closed."""
        with self._cond:
            while self._frames >= self.maxsize and not self._closed:
                self._cond.wait()
            if self._closed:
                return False
            self._append(item)
            self._cond.notify_all()
            return True

    def put_control(self, fn: Callable[[], None], force: bool = False) -> bool:
        """Queue a control callable; False (not queued) when ``max_control`` are waiting,
        unless ``force`` (the service's own, bounded by the sensors it takes over)."""
        with self._cond:
            if len(self._control) >= self.max_control and not force:
                return False
            if not self._control:
                self._ring.append(_CONTROL)
            self._control.append(fn)
            self._cond.notify_all()
            return True

    def get(self, timeout: float) -> Inbound | Dropped | Callable[[], None] | None:
        """The next lane's next item: its pending drop notice first, else its oldest frame;
        the control lane gives one callable per turn. None on timeout or when closed and
        empty (check ``closed``)."""
        with self._cond:
            deadline = time.monotonic() + timeout
            while not self._ring:
                remaining = deadline - time.monotonic()
                if self._closed or remaining <= 0:
                    return None
                self._cond.wait(remaining)
            key = self._ring.popleft()
            if key == _CONTROL:
                fn = self._control.popleft()
                if self._control:
                    self._ring.append(_CONTROL)
                return fn
            lane = self._lanes[key]
            item: Inbound | Dropped
            if lane.drops:
                item = lane.drops.popleft()
            else:
                item = self._pop_frame(lane)
                self._cond.notify_all()  # room for a blocked producer
            if lane.frames or lane.drops:
                self._ring.append(key)
            else:
                del self._lanes[key]
            return item

    def close(self) -> None:
        """Refuse new frames; queued ones (and notices) are still handed out."""
        with self._cond:
            self._closed = True
            self._cond.notify_all()


def _depth(lane: _Lane) -> int:
    return len(lane.frames)


def worker_index(key: str, workers: int) -> int:
    # crc32, not hash(): stable across processes so logs and restarts agree.
    return zlib.crc32(key.encode()) % workers


class Intake:
    """The subscriber callback: route each sample to its worker's queue."""

    def __init__(
        self,
        queues: list[WorkQueue],
        policy: Backpressure,
        on_received: Callable[[str], None],
        on_dropped: Callable[[Inbound, ErrorReason], None],
        wanted: Callable[[str], bool] | None = None,
        route: Callable[[str], str] | None = None,
    ) -> None:
        """``route(key)``: what picks a key's worker (a fused sensor's: its vehicle's)."""
        self._queues = queues
        self._route = route or (lambda key: key)
        self._block = policy is Backpressure.BLOCK
        self._on_received = on_received
        self._on_dropped = on_dropped
        # False: another member owns the key and this one does not stand by for it.
        self._wanted = wanted

    def handler(
        self, callback: Callable[[zenoh.Sample], None] | None = None
    ) -> zenoh.handlers.Callback[zenoh.Sample]:
        """The subscriber's handler, calling ``callback`` (a wrapper that ends in this
        intake) or the intake itself. With ``drop_oldest`` the callback never blocks, so it
        runs on the Zenoh thread of each link: a flood on one link then waits for the
        interpreter lock, not in a FIFO shared with every other sensor's samples (the default
        handler's thread). ``block`` keeps that thread: waiting for room must not stall
        Zenoh's own."""
        return zenoh.handlers.Callback(callback or self, indirect=self._block)

    def __call__(self, sample: zenoh.Sample) -> None:
        key = str(sample.key_expr)
        if self._wanted is not None and not self._wanted(key):
            return  # before any copy: the cheapest a frame of another member can cost
        item = Inbound(key, sample.payload.to_bytes(), time.time_ns(), time.perf_counter())
        self._on_received(key)
        self._enqueue(self._route(key), item)

    def checkpoint(self, sample: zenoh.Sample, detections_key: str) -> None:
        """A checkpoint goes to the worker of the sensor it is of (its own lane)."""
        key = str(sample.key_expr)
        payload = sample.payload.to_bytes()
        item = Inbound(key, payload, time.time_ns(), time.perf_counter(), Kind.CHECKPOINT)
        self._enqueue(detections_key, item)

    def _enqueue(self, route: str, item: Inbound) -> None:
        q = self._queues[worker_index(route, len(self._queues))]
        if self._block:
            accepted, evicted = q.put_blocking(item), None
        else:
            accepted, evicted = q.put_drop_oldest(item)
        if evicted is not None:
            self._on_dropped(evicted, ErrorReason.DROPPED_QUEUE_FULL)
        if not accepted:
            self._on_dropped(item, ErrorReason.DROPPED_SHUTDOWN)


def depth(queues: list[WorkQueue]) -> int:
    return sum(len(q) for q in queues)


__all__ = [
    "MAX_QUERIES",
    "Dropped",
    "Inbound",
    "Intake",
    "Kind",
    "WorkQueue",
    "depth",
    "stamp_of",
    "worker_index",
]
