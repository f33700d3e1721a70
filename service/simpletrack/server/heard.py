"""What a member heard on the tracks keys of the streams it owns or stands by for: how far
planners have each stream, the ids it holds (a takeover neither repeats nor reuses them) and
its newest message (a failover whose checkpoint holds that frame publishes it again).

A stream's standby is told those by its owner, in batches (server/told.py), and gets
the newest message with each checkpoint; an owner hears those other members put on its
streams' keys (and a sensor's standby, while its vehicle waits to fuse, the sensor's). Read one
at a time on Zenoh's thread, each message paid for its parse with cold caches: at 10 Hz a
stream, nothing of the parse's code or memory is still warm from the message before
(docs/BENCHMARKS.md, "What each role costs per frame"). So the Zenoh callback judges the
message as it comes (server/app.py: the stream's role, whether a worker holds it) and keeps
it (``add``, ``told``); they are read together, once ``batch`` are waiting or ``batch_s``
after the first of them came. Whatever looks at what was heard (``get``,
``forget_payloads``) reads the waiting ones first: it never sees less than what had arrived
when it looked.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable
from dataclasses import replace

from simpletrack.server.custody_machine import Heard
from simpletrack.server.logs import get_logger
from simpletrack.server.told import Told
from simpletrack.wire.header import peek_heard, peek_vehicle_heard

log = get_logger("heard")

__all__ = ["BATCH", "BATCH_S", "MAX_STREAMS", "HeardStreams"]

BATCH = 64  # messages read together (0.16 s of 40 streams at 10 Hz)
BATCH_S = 0.5  # the longest a message waits for others (a reader reads it at once)
MAX_STREAMS = 1_000_000  # bounded: a flood of made-up keys cannot grow it


class HeardStreams:
    """Per stream (``vehicle/sensor``, or ``vehicle/@vehicle`` for a fused vehicle's tracks),
    the latest message heard. ``own`` is this member's instance as its messages carry it
    (msgpack of the key and the name): its own messages teach nothing. Thread-safe."""

    def __init__(
        self,
        own: bytes,
        batch: int = BATCH,
        batch_s: float = BATCH_S,
        clock: Callable[[], float] = time.monotonic,
        max_streams: int = MAX_STREAMS,
    ) -> None:
        if batch < 1:
            raise ValueError(f"batch must be at least 1, got {batch}")
        if not batch_s >= 0:
            raise ValueError(f"batch_s must be >= 0, got {batch_s}")
        self._own, self._batch, self._batch_s, self._clock = own, batch, batch_s, clock
        self._max_streams = max_streams
        # Held while messages are read: a reader that asks waits for a batch being read.
        self._lock = threading.Lock()
        self._waiting: list[tuple[str, bytes, bool] | Told] = []
        self._first_at = 0.0
        self._streams: dict[str, Heard] = {}

    def add(self, stream: str, payload: bytes, vehicle: bool = False) -> None:
        """A tracks message heard on ``stream``'s key (``vehicle``: a VehicleTrackFrame),
        kept to be read with the next batch."""
        self._keep((stream, payload, vehicle))

    def told(self, told: Told) -> None:
        """What a stream's owner told this member, its standby, of a message it published
        (server/told.py), kept to be read with the next batch."""
        self._keep(told)

    def _keep(self, entry: tuple[str, bytes, bool] | Told) -> None:
        with self._lock:
            now = self._clock()
            if not self._waiting:
                self._first_at = now
            self._waiting.append(entry)
            if len(self._waiting) >= self._batch or now - self._first_at >= self._batch_s:
                self._read_waiting()

    def get(self, stream: str) -> Heard | None:
        with self._lock:
            self._read_waiting()
            return self._streams.get(stream)

    def forget_payloads(self, keep: Callable[[str], bool]) -> None:
        """Drop the newest message of each stream ``keep`` refuses (its stamp and ids stay)."""
        with self._lock:
            self._read_waiting()
            for stream, heard in list(self._streams.items()):
                if heard.payload is not None and not keep(stream):
                    self._streams[stream] = replace(heard, payload=None)

    def __len__(self) -> int:
        with self._lock:
            self._read_waiting()
            return len(self._streams)

    def _read_waiting(self) -> None:
        waiting, self._waiting = self._waiting, []
        for entry in waiting:
            if isinstance(entry, Told):
                self._record(
                    entry.stream, entry.stamp_ns, entry.next_id, entry.seq, entry.epoch, None
                )
                continue
            stream, payload, vehicle = entry
            try:
                self._read(stream, payload, vehicle)
            except Exception:  # one bad message must not cost the others theirs
                log.error("heard_unreadable", exc=True, stream=stream)

    def _read(self, stream: str, payload: bytes, vehicle: bool) -> None:
        # Published here (before a fence or a release): no sign of what planners have from
        # the others.
        if self._own in payload:
            return
        if vehicle:
            read = peek_vehicle_heard(payload)
            if read is not None:
                self._record(stream, *read, payload)
            return
        peeked = peek_heard(payload)
        if peeked is not None:
            stamp_ns, next_id, epoch = peeked
            self._record(stream, stamp_ns, next_id, None, epoch, payload)

    def _record(
        self,
        stream: str,
        stamp_ns: int,
        next_id: int,
        seq: int | None,
        epoch: int | None,
        payload: bytes | None,
    ) -> None:
        old = self._streams.get(stream)
        if old is not None:
            if payload is None:  # told: the message kept stays while it is the newest
                payload = old.payload if stamp_ns <= old.stamp_ns else None
            else:
                payload = payload if stamp_ns >= old.stamp_ns else old.payload
            self._streams[stream] = Heard(
                max(old.stamp_ns, stamp_ns),
                max(old.next_id, next_id),
                _top(old.seq, seq),
                _top(old.epoch, epoch),
                payload,
            )
        elif len(self._streams) < self._max_streams:
            self._streams[stream] = Heard(stamp_ns, next_id, seq, epoch, payload)


def _top(a: int | None, b: int | None) -> int | None:
    return a if b is None else b if a is None else max(a, b)
