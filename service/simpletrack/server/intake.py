"""From Zenoh to the workers: the subscriber callback and each worker's bounded, fair queue.

The callback does no decoding and no tracking: it copies the payload out of Zenoh, stamps
the receipt time and appends to the queue of the worker that owns the key (a sensor always
maps to the same worker, which keeps its frames in order).

Inside a worker's queue every key has its own lane and the worker serves the lanes in turn
(round robin), with the snapshot queries as one more lane: a sensor that floods, or a flood
of queries, waits behind itself, never in front of its neighbours (docs/SERVICE.md, "What a
fault can cost").

Catch-up frames (docs/SERVICE.md, "Recovered frames are kept"): a frame that arrives further
behind its stamp than its sensor's usual delay (recovered from a vehicle's cache after an
outage, replayed at a takeover), and the few frames of that sensor queued behind it, are kept
beyond ``queue_size`` on the member's ``BurstBudget`` (bytes) instead of being shed: the lane
policy only ever evicts fresh frames. A catch-up frame the budget has no room for is refused
and announced as ``missed``.

Checkpoints (another member's state of a sensor this one stands by for) never count against
``queue_size`` and are never shed: a newer one of a key replaces the one waiting (each is a
sensor's whole state, the older worthless; of two, the one written later stays), so at most
one per sensor stood by for waits (``MAX_CHECKPOINTS`` sensors a worker; a new one past it is
refused and counted). An owner sends its changed sensors' states all at once every ``checkpoint_interval_s``; counted
as frames, that burst shed this member's own frames once it stood by for a few hundred
sensors (a queue of 64 held 58 checkpoints).
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

from simpletrack.server.gil import Trackers
from simpletrack.server.settings import Backpressure
from simpletrack.wire.header import peek_header, peek_written
from simpletrack.wire.messages import MAX_NOTICE_SEQS
from simpletrack.wire.reasons import ErrorReason

# Snapshot queries waiting per worker; more are refused at once (the querier gets an error).
MAX_QUERIES = 16
# Sensors with a checkpoint waiting per worker (one each): far above the hundreds a member
# stands by for, a bound on what another member's bug or a stranger's keys can hold here.
MAX_CHECKPOINTS = 4096
_CONTROL = ""  # the queries' place in the rotation: no Zenoh key is empty

# What a kept frame costs the burst budget beyond its payload: the Inbound, its key and its
# entry in the lane (~430 B measured with tracemalloc on CPython 3.11), rounded up.
FRAME_OVERHEAD = 512
# The setting catchup_after_s's default: how much further behind its stamp than usual a frame
# must arrive to be a catch-up frame. Well above delivery jitter (ms) and a GIL-bound worker's
# waits, well below a router outage (seconds) or a vehicle's 10 s cache.
CATCHUP_AFTER_S = 0.5
# A sensor's usual delay (receipt - stamp, clock offset included) is the least seen, let rise
# by 1/LAG_RISE of the time since (10 ms per s): a clock stepped back is relearned in a
# minute, and a 10 s outage moves it by only 0.1 s.
LAG_RISE = 100
# Sensors whose usual delay a queue remembers; past it, the longest known is forgotten (its
# next frame counts as its first).
MAX_CLOCKS = 16_384


class Kind(Enum):
    DETECTIONS = "detections"
    CHECKPOINT = "checkpoint"  # another member's state of a sensor this one stands by for


# The attachment of the checkpoints a member sends as it stops, after every frame's tracks
# went out: a failover from one has nothing to publish again (custody_machine.answered).
FINAL_CHECKPOINT = b"final"


@dataclass(frozen=True, slots=True)
class Inbound:
    """A payload as received: its key, bytes, and when it arrived."""

    key: str
    payload: bytes
    received_ns: int  # wall clock (unix ns): goes on the wire
    received_at: float  # time.perf_counter(): measures the queue wait
    kind: Kind = Kind.DETECTIONS
    # The publisher's Zenoh sequence number, for a frame a vehicle's cache answered (its
    # first sample is 0): how many it published before; None for a live frame (not read).
    source_sn: int | None = None
    final: bool = False  # a checkpoint its holder sent as it stopped (FINAL_CHECKPOINT)
    tracks: bytes | None = None  # a checkpoint's stream's newest tracks message


def stamp_of(item: Inbound) -> int | None:
    """The frame's ``stamp_ns`` from its header alone (None: unreadable)."""
    return peek_header(item.payload)[1]


class BurstBudget:
    """The bytes a member may hold beyond its queues' ``queue_size`` (setting ``burst_bytes``),
    shared by every worker's queue of the member (and by whatever else keeps frames waiting,
    e.g. a takeover's): ``take(n)`` reserves, ``give(n)`` returns. Thread-safe; never waits."""

    def __init__(self, limit: int) -> None:
        if limit < 0:
            raise ValueError(f"a burst budget cannot be negative: {limit}")
        self.limit = limit
        self._in_use = 0
        self._peak = 0
        self._kept = 0
        self._lock = threading.Lock()

    @property
    def in_use(self) -> int:
        """Bytes taken and not yet given back."""
        return self._in_use

    @property
    def peak(self) -> int:
        """The most bytes ever in use at once."""
        return self._peak

    @property
    def kept(self) -> int:
        """Frames the queues kept beyond ``queue_size`` so far (``take(..., kept=True)``)."""
        return self._kept

    def take(self, n: int, *, kept: bool = False) -> bool:
        """Reserve ``n`` bytes; False (nothing reserved) when that would pass the limit.
        ``kept``: the bytes are a frame a queue keeps beyond ``queue_size`` (counted)."""
        if n < 0:
            raise ValueError(f"cannot take {n} bytes")
        with self._lock:
            if self._in_use + n > self.limit:
                return False
            self._in_use += n
            self._peak = max(self._peak, self._in_use)
            self._kept += kept
            return True

    def give(self, n: int) -> None:
        """Return ``n`` bytes taken before."""
        with self._lock:
            if n < 0 or n > self._in_use:
                raise ValueError(f"cannot give back {n} bytes: {self._in_use} in use")
            self._in_use -= n


@dataclass(slots=True)
class Dropped:
    """Frames of one key the queue had to give up, announced by the worker in one notice."""

    key: str
    reason: ErrorReason
    seqs: list[int | None]  # None: the frame's seq could not be read
    stamp_ns: int | None  # of the first frame
    received_ns: int  # when the first frame arrived


Header = tuple[int | None, int | None]  # (seq, stamp_ns) as peek_header reads them


@dataclass(slots=True)
class _Entry:
    n: int  # arrival order in the queue: a lane's two kinds of frames are served merged by it
    item: Inbound
    header: Header | None  # None: not read yet
    cost: int = 0  # bytes on the burst budget: 0 for a fresh frame
    behind: bool = False  # kept as a catch-up frame (else fresh, or kept as a follower)


@dataclass(slots=True)
class _Lane:
    fresh: deque[_Entry] = field(default_factory=deque)  # count against queue_size
    kept: deque[_Entry] = field(default_factory=deque)  # on the burst budget, never evicted
    checkpoint: _Entry | None = None  # the newest state of the key waiting, never evicted
    drops: deque[Dropped] = field(default_factory=deque)
    behind: int = 0  # catch-up frames among ``kept``; the others follow them


class WorkQueue:
    """The frames waiting for one worker, in one lane per key: at most ``maxsize`` fresh ones
    in all, plus the catch-up frames kept on ``budget``; the drop notices of each lane; and a
    bounded lane of control callables (queries). ``get`` serves the lanes in turn, one item
    per turn.

    Without a ``budget`` every frame is fresh (the queue of before). With one, a detection
    frame that arrives over ``catchup_after_s`` further behind its stamp than its sensor's
    usual delay is a catch-up frame, and so are up to ``maxsize`` frames of its sensor that
    arrive while one waits (the rest of the same burst: frames published while the link came
    back); they are kept beyond ``maxsize``, on the budget, until served, and never evicted.
    """

    def __init__(
        self,
        maxsize: int,
        max_control: int = MAX_QUERIES,
        *,
        max_checkpoints: int = MAX_CHECKPOINTS,
        budget: BurstBudget | None = None,
        catchup_after_s: float = CATCHUP_AFTER_S,
    ) -> None:
        if catchup_after_s <= 0:
            raise ValueError(f"catchup_after_s must be positive: {catchup_after_s}")
        self.maxsize, self.max_control = maxsize, max_control
        self.max_checkpoints = max_checkpoints
        self.budget = budget
        self._catchup_ns = round(catchup_after_s * 1e9)
        self._lanes: dict[str, _Lane] = {}  # keys with frames or notices waiting
        self._ring: deque[str] = deque()  # the keys of _lanes (and _CONTROL) in serving order
        self._control: deque[Callable[[], None]] = deque()
        self._frames = 0  # fresh and kept
        self._checkpoints = 0  # lanes holding one
        self._fresh = 0
        self._busy = 0  # lanes holding fresh frames
        self._arrivals = 0
        # key -> [usual delay (ns), when it was last set (received_ns)]
        self._clocks: dict[str, list[int]] = {}
        self._cond = threading.Condition()
        self._closed = False

    def __len__(self) -> int:
        return self._frames

    @property
    def checkpoints(self) -> int:
        """Checkpoints waiting (one per key at most), apart from the frames."""
        return self._checkpoints

    @property
    def kept(self) -> int:
        """Frames waiting beyond ``maxsize`` on the burst budget."""
        return self._frames - self._fresh

    @property
    def closed(self) -> bool:
        return self._closed

    def _lane(self, key: str) -> _Lane:
        lane = self._lanes.get(key)
        if lane is None:
            lane = self._lanes[key] = _Lane()
            self._ring.append(key)
        return lane

    def _entry(self, item: Inbound, header: Header | None) -> _Entry:
        self._arrivals += 1
        return _Entry(self._arrivals, item, header)

    def _append_fresh(self, entry: _Entry) -> None:
        lane = self._lane(entry.item.key)
        if not lane.fresh:
            self._busy += 1
        lane.fresh.append(entry)
        self._fresh += 1
        self._frames += 1

    def _pop_fresh(self, lane: _Lane) -> _Entry:
        entry = lane.fresh.popleft()
        self._fresh -= 1
        self._frames -= 1
        if not lane.fresh:
            self._busy -= 1
        return entry

    def _pop_next(self, lane: _Lane) -> _Entry:
        """The lane's oldest item: its checkpoint, or a frame, fresh or kept (a kept frame's
        bytes back to the budget)."""
        mark = lane.checkpoint
        if mark is not None and all(not d or mark.n < d[0].n for d in (lane.fresh, lane.kept)):
            lane.checkpoint = None
            self._checkpoints -= 1
            return mark
        if lane.kept and (not lane.fresh or lane.kept[0].n < lane.fresh[0].n):
            entry = lane.kept.popleft()
            self._frames -= 1
            lane.behind -= entry.behind
            if self.budget is not None:
                self.budget.give(entry.cost)
            return entry
        return self._pop_fresh(lane)

    def _header(self, item: Inbound) -> Header | None:
        """A detection frame's header when catch-up frames are told apart (read before the
        lock is taken: it parses the payload); else None, read only if it is shed."""
        if self.budget is None or item.kind is not Kind.DETECTIONS:
            return None
        return peek_header(item.payload)

    def _is_behind(self, key: str, received_ns: int, stamp_ns: int | None) -> bool:
        """Whether a frame arrives over catchup_after_s later after its stamp than its
        sensor's usual delay; learns that delay (the least seen, rising slowly). A sensor's
        first frame sets it: a frame judged against its own sensor, never against the
        service's clock, so a vehicle whose clock is off is judged like any other."""
        if stamp_ns is None:
            return False
        lag = received_ns - stamp_ns
        clock = self._clocks.get(key)
        if clock is None:
            if len(self._clocks) >= MAX_CLOCKS:
                del self._clocks[next(iter(self._clocks))]
            self._clocks[key] = [lag, received_ns]
            return False
        usual = clock[0] + max(0, received_ns - clock[1]) // LAG_RISE
        if lag <= usual:
            clock[0], clock[1] = lag, received_ns
            return False
        return lag - usual > self._catchup_ns

    def _keep(self, item: Inbound, header: Header | None, refuse: bool) -> bool | None:
        """Keep a catch-up frame (or one following catch-up frames of its lane) beyond
        maxsize on the budget: True if kept; False if it is fresh, or a follower or (when not
        ``refuse``) a catch-up frame the budget has no room for: the caller queues it as
        fresh; None: a catch-up frame refused (the caller announces it missed)."""
        if header is None:
            return False
        behind = self._is_behind(item.key, item.received_ns, header[1])
        lane = self._lanes.get(item.key)
        # Frames of the same burst behind it (published while the link came back) follow a
        # catch-up frame, at most maxsize of them: a sensor cannot keep a flood this way.
        followers = 0 if lane is None else len(lane.kept) - lane.behind
        follows = lane is not None and lane.behind > 0 and followers < self.maxsize
        if not (behind or follows):
            return False
        assert self.budget is not None  # a header is read only with a budget
        cost = len(item.payload) + FRAME_OVERHEAD
        if not self.budget.take(cost, kept=True):
            return None if behind and refuse else False
        entry = self._entry(item, header)
        entry.cost, entry.behind = cost, behind
        lane = self._lane(item.key)
        lane.kept.append(entry)
        lane.behind += behind
        self._frames += 1
        return True

    def _victim(self, arriving: str) -> _Lane:
        """The lane that gives up its oldest fresh frame when the queue is full: the arriving
        key's own when it holds at least an equal share of them, else the one holding the
        most. Kept frames are never chosen."""
        own = self._lanes.get(arriving)
        if own is not None and len(own.fresh) * self._busy >= self._fresh:
            return own
        return max((lane for lane in self._lanes.values() if lane.fresh), key=_depth)

    def put_drop_oldest(self, item: Inbound) -> tuple[bool, Inbound | None]:
        """Enqueue; a full queue gives up the oldest fresh frame of its fullest lane, returned
        (its notice is queued for the worker to publish). ``(False, None)`` if closed;
        ``(False, item)``: a catch-up frame refused, the budget being spent (its ``missed``
        notice is queued)."""
        if item.kind is Kind.CHECKPOINT:
            return self.put_checkpoint(item), None
        header = self._header(item)
        with self._cond:
            if self._closed:
                return False, None
            kept = self._keep(item, header, refuse=True)
            evicted = None
            if kept is False:
                if self._fresh >= self.maxsize:
                    evicted = self._pop_fresh(self._victim(item.key))
                self._append_fresh(self._entry(item, header))
            if kept is not None:
                self._cond.notify()
        if kept is None:
            assert header is not None
            self.note_drop(item, ErrorReason.MISSED, *header)
            return False, item
        if evicted is None:
            return True, None
        # Only the header is read, and outside the lock: the worker keeps going meanwhile.
        seq, stamp_ns = evicted.header or peek_header(evicted.item.payload)
        self.note_drop(evicted.item, ErrorReason.DROPPED_QUEUE_FULL, seq, stamp_ns)
        return True, evicted.item

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
        """Enqueue, waiting for room (pushes back on Zenoh). False if the queue is closed.
        A catch-up frame is kept on the budget without waiting; one the budget has no room
        for waits like a fresh frame: block mode never loses one. A checkpoint never waits."""
        if item.kind is Kind.CHECKPOINT:
            return self.put_checkpoint(item)
        header = self._header(item)
        with self._cond:
            if self._closed:
                return False
            if not self._keep(item, header, refuse=False):
                while self._fresh >= self.maxsize and not self._closed:
                    self._cond.wait()
                if self._closed:
                    return False
                self._append_fresh(self._entry(item, header))
            self._cond.notify_all()
            return True

    def put_checkpoint(self, item: Inbound) -> bool:
        """Queue a checkpoint in place of its key's waiting one, if any. False if closed, or
        (refused) when ``max_checkpoints`` keys have one waiting already."""
        with self._cond:
            if self._closed:
                return False
            lane = self._lanes.get(item.key)
            waiting = None if lane is None else lane.checkpoint
            if waiting is None:
                if self._checkpoints >= self.max_checkpoints:
                    return False
                self._checkpoints += 1
            elif _overtaken(item, waiting.item):
                return True  # as the custody machine would: the newer state stays
            self._lane(item.key).checkpoint = self._entry(item, None)
            self._cond.notify()
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
                entry = self._pop_next(lane)
                item = entry.item
                if not entry.cost:
                    self._cond.notify_all()  # room for a blocked producer
            if lane.fresh or lane.kept or lane.drops or lane.checkpoint:
                self._ring.append(key)
            else:
                del self._lanes[key]
            return item

    def close(self) -> None:
        """Refuse new frames; queued ones (and notices) are still handed out."""
        with self._cond:
            self._closed = True
            self._cond.notify_all()


def _overtaken(arriving: Inbound, waiting: Inbound) -> bool:
    """The arriving state is older than the one waiting (two members sent one each, e.g.
    after a partition; or one overtook the other on the way). Read only then: rare."""
    new, old = peek_written(arriving.payload), peek_written(waiting.payload)
    return new is not None and old is not None and new < old


def _depth(lane: _Lane) -> int:
    return len(lane.fresh)


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
        trackers: Trackers | None = None,
    ) -> None:
        """``route(key)``: what picks a key's worker (a fused sensor's: its vehicle's).
        ``trackers``: the workers tracking now, whom a sample shedding its own lane lets
        have the interpreter lock first (server/gil.py)."""
        self._queues = queues
        self._trackers = trackers
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
        self._take(key, sample.payload.to_bytes())

    def inject(self, key: str, payload: bytes) -> None:
        """A frame heard on the detections key by other means (a plain sensor's frames kept
        by the group's scout), received now."""
        if self._wanted is None or self._wanted(key):
            self._take(key, payload)

    def _take(self, key: str, payload: bytes) -> None:
        self._on_received(key)
        self._enqueue(self._route(key), Inbound(key, payload, time.time_ns(), time.perf_counter()))

    def checkpoint(self, sample: zenoh.Sample, detections_key: str) -> None:
        """A checkpoint goes to the worker of the sensor it is of (its own lane)."""
        key = str(sample.key_expr)
        payload = sample.payload.to_bytes()
        attachment = sample.attachment
        extra = None if attachment is None else attachment.to_bytes()
        final = extra == FINAL_CHECKPOINT
        # Otherwise the stream's newest tracks message (server/told.py): a failover whose
        # state holds its frame publishes it again.
        tracks = None if final or not extra else extra
        item = Inbound(
            key,
            payload,
            time.time_ns(),
            time.perf_counter(),
            Kind.CHECKPOINT,
            final=final,
            tracks=tracks,
        )
        self._enqueue(detections_key, item)

    def _enqueue(self, route: str, item: Inbound) -> None:
        q = self._queues[worker_index(route, len(self._queues))]
        if item.kind is Kind.CHECKPOINT:
            if not q.put_checkpoint(item) and not q.closed:
                self._on_dropped(item, ErrorReason.DROPPED_QUEUE_FULL)  # counted, not announced
            return
        if self._block:
            accepted, evicted = q.put_blocking(item), None
        else:
            accepted, evicted = q.put_drop_oldest(item)
        if evicted is item:  # a catch-up frame the burst budget had no room for
            self._on_dropped(item, ErrorReason.MISSED)
        elif evicted is not None:
            self._on_dropped(evicted, ErrorReason.DROPPED_QUEUE_FULL)
            if evicted.key == item.key and self._trackers is not None:
                self._trackers.pause()  # a flood: the frames being tracked go first
        if not accepted and evicted is None:
            self._on_dropped(item, ErrorReason.DROPPED_SHUTDOWN)


def depth(queues: list[WorkQueue]) -> int:
    return sum(len(q) for q in queues)


__all__ = [
    "CATCHUP_AFTER_S",
    "FINAL_CHECKPOINT",
    "FRAME_OVERHEAD",
    "MAX_CHECKPOINTS",
    "MAX_QUERIES",
    "BurstBudget",
    "Dropped",
    "Inbound",
    "Intake",
    "Kind",
    "WorkQueue",
    "depth",
    "stamp_of",
    "worker_index",
]
