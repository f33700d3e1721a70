"""From Zenoh to the workers: the subscriber callback and the bounded per-worker queues.

The callback does no decoding and no tracking: it copies the payload out of Zenoh, stamps
the receipt time and appends to the queue of the worker that owns the key (a sensor always
maps to the same worker, which keeps its frames in order).
"""

from __future__ import annotations

import threading
import time
import zlib
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass

import zenoh

from simpletrack.server.settings import Backpressure
from simpletrack.wire.reasons import ErrorReason


@dataclass(frozen=True, slots=True)
class Inbound:
    """A detection payload as received: its key, bytes, and when it arrived."""

    key: str
    payload: bytes
    received_ns: int  # wall clock (unix ns): goes on the wire
    received_at: float  # time.perf_counter(): measures the queue wait


@dataclass(frozen=True, slots=True)
class Dropped:
    """A frame the queue had to give up, to be reported on the errors key by the worker."""

    item: Inbound
    reason: ErrorReason


class WorkQueue:
    """Bounded FIFO of frames for one worker, plus an unbounded lane of control callables
    (snapshot queries) served before frames, and a bounded lane of drop notices."""

    def __init__(self, maxsize: int) -> None:
        self.maxsize = maxsize
        self._frames: deque[Inbound] = deque()
        self._dropped: deque[Dropped] = deque(maxlen=max(1024, 4 * maxsize))
        self._control: deque[Callable[[], None]] = deque()
        self._cond = threading.Condition()
        self._closed = False

    def __len__(self) -> int:
        return len(self._frames)

    @property
    def closed(self) -> bool:
        return self._closed

    def put_drop_oldest(self, item: Inbound) -> tuple[bool, Inbound | None]:
        """Enqueue; a full queue gives up its oldest frame, returned (its notice is queued
        for the worker to publish). ``(False, None)`` if the queue is closed."""
        with self._cond:
            if self._closed:
                return False, None
            evicted = None
            if len(self._frames) >= self.maxsize:
                evicted = self._frames.popleft()
                self._dropped.append(Dropped(evicted, ErrorReason.DROPPED_QUEUE_FULL))
            self._frames.append(item)
            self._cond.notify()
            return True, evicted

    def put_blocking(self, item: Inbound) -> bool:
        """Enqueue, waiting for room (pushes back on Zenoh). False if the queue is closed."""
        with self._cond:
            while len(self._frames) >= self.maxsize and not self._closed:
                self._cond.wait()
            if self._closed:
                return False
            self._frames.append(item)
            self._cond.notify_all()
            return True

    def put_control(self, fn: Callable[[], None]) -> None:
        with self._cond:
            self._control.append(fn)
            self._cond.notify_all()

    def get(self, timeout: float) -> Inbound | Dropped | Callable[[], None] | None:
        """Next control callable, drop notice or frame; None on timeout or when closed and
        empty (check ``closed``)."""
        with self._cond:
            deadline = time.monotonic() + timeout
            while not (self._control or self._dropped or self._frames):
                remaining = deadline - time.monotonic()
                if self._closed or remaining <= 0:
                    return None
                self._cond.wait(remaining)
            if self._control:
                return self._control.popleft()
            if self._dropped:
                return self._dropped.popleft()
            item = self._frames.popleft()
            self._cond.notify_all()  # room for a blocked producer
            return item

    def close(self) -> None:
        """Refuse new frames; queued ones are still handed out."""
        with self._cond:
            self._closed = True
            self._cond.notify_all()


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
    ) -> None:
        self._queues = queues
        self._block = policy is Backpressure.BLOCK
        self._on_received = on_received
        self._on_dropped = on_dropped

    def __call__(self, sample: zenoh.Sample) -> None:
        key = str(sample.key_expr)
        item = Inbound(key, sample.payload.to_bytes(), time.time_ns(), time.perf_counter())
        self._on_received(key)
        q = self._queues[worker_index(key, len(self._queues))]
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


__all__ = ["Dropped", "Inbound", "Intake", "WorkQueue", "depth", "worker_index"]
