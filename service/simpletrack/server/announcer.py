"""The member's refusal notices (``FrameError`` on each sensor's errors key), published from a
thread of their own.

Errors are published with the ``congestion_control`` setting (``block`` by default), and a
blocking put waits while the link to a subscriber of that key has no room: a subscriber of
``<prefix>/*/*/errors`` slower than a garbage flood is refused held every put on its link.
Published by the workers, such a put held the worker, and every sensor on it waited (a new
sensor's second frame 0.35-1.2 s). The workers hand their encoded notices here and go on;
so does the miss listener (server/misses.py), with the notice of frames lost in transport.

- **Order.** One FIFO for the member: a sensor's notices are published in the order its
  worker handed them over. A tracks message of a sensor with notices still waiting here goes
  behind them (``behind``), so a subscriber hears of a sensor's frames in the order they were
  answered, as when the worker published both.
- **Bounded.** At most ``limit_bytes`` wait (payload + ITEM_OVERHEAD each). A notice past the
  bound is not published: counted in ``simpletrack_error_notices_dropped_total`` and logged
  (``error_notices_dropped``, the first at once, then at most one line per ``log_interval_s``
  with how many since), never silently; its frame stays counted where it always was
  (``simpletrack_frames_rejected_total`` / ``simpletrack_frames_dropped_total``). A tracks
  message is never dropped: past the bound its worker publishes it itself.
- **At the stop** what still waits is published until the deadline; what is left then is
  counted and logged as dropped.
"""

from __future__ import annotations

import threading
import time
from collections import deque
from collections.abc import Callable

import zenoh

from simpletrack.server.logs import get_logger
from simpletrack.server.metrics import Metrics
from simpletrack.server.outbox import REFUSAL_LOG_S, put

log = get_logger("pool")
# Bytes of notices (and of tracks held behind them) that may wait: ~80,000 refusals of garbage
# (152 B each + ITEM_OVERHEAD), seconds of the worst flood a member refuses; far above what a
# subscriber keeping up ever leaves waiting (a put takes microseconds).
ANNOUNCE_BYTES = 32 << 20
# What a waiting item costs beyond its payload (its tuple, key and deque slot), rounded up.
ITEM_OVERHEAD = 256

Stream = tuple[str, str]  # (vehicle, sensor)
_Item = tuple[str, bytes, Stream, int]  # key, payload, its stream, its cost in bytes


class Announcer:
    """Publishes what the workers hand over, in order, from one thread (``start``/``close``).
    ``announce`` and ``behind`` never wait for Zenoh."""

    def __init__(
        self,
        session: zenoh.Session,
        congestion: zenoh.CongestionControl,
        metrics: Metrics,
        limit_bytes: int = ANNOUNCE_BYTES,
        log_interval_s: float = REFUSAL_LOG_S,
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        self._session, self._congestion, self._metrics = session, congestion, metrics
        self.limit_bytes, self._log_interval_s, self._clock = limit_bytes, log_interval_s, clock
        self._items: deque[_Item] = deque()
        self._bytes = 0
        # stream -> its items waiting or being published. Only a stream's own worker and the
        # miss listener add to it, the listener before it hands on the frames after a gap:
        # a stream absent here has nothing pending that a worker's frame must follow (read
        # without the lock).
        self._pending: dict[Stream, int] = {}
        self._cond = threading.Condition()
        self._closing = False
        self._abandoned = False  # past the stop's deadline: publish nothing more
        self._batch: list[_Item] = []  # what the thread publishes now, from ``_next`` on
        self._next = 0
        self._unlogged = 0  # notices dropped since the last log line
        self._last_dropped: Stream | None = None
        self._next_log = 0.0  # the first drop is logged at once
        self._thread = threading.Thread(target=self._run, name="announcer", daemon=True)
        metrics.error_notices_waiting.set_function(lambda: len(self._items))

    def start(self) -> None:
        self._thread.start()

    def announce(self, key: str, payload: bytes, stream: Stream) -> bool:
        """Queue a notice; False when the backlog is full (then counted and logged)."""
        cost = len(payload) + ITEM_OVERHEAD
        with self._cond:
            if not self._closing and self._bytes + cost <= self.limit_bytes:
                self._push((key, payload, stream, cost))
                return True
            logged = self._dropped(stream)
        self._metrics.error_notices_dropped.inc()
        self._log(logged)
        return False

    def behind(self, key: str, payload: bytes, stream: Stream) -> bool:
        """Queue a tracks message behind its stream's waiting notices: True when it was (it
        is published from here); False when none wait, or the backlog is full: the caller
        publishes it itself."""
        if stream not in self._pending:  # the usual case, without the lock
            return False
        cost = len(payload) + ITEM_OVERHEAD
        with self._cond:
            if self._closing or stream not in self._pending:
                return False
            if self._bytes + cost > self.limit_bytes:
                return False
            self._push((key, payload, stream, cost))
            return True

    def pending(self, stream: Stream) -> int:
        """Items of a stream waiting or being published."""
        return self._pending.get(stream, 0)

    def flush_logs(self) -> None:
        """Log the notices dropped since the last line once its interval has passed (a
        worker's housekeeping calls it: the announcer's thread may be held in a put)."""
        with self._cond:
            logged = self._due()
        self._log(logged)

    def close(self, timeout: float) -> None:
        """Publish what waits, for at most ``timeout`` seconds; count and log the rest."""
        with self._cond:
            self._closing = True
            self._cond.notify_all()
        if self._thread.is_alive():
            self._thread.join(max(0.0, timeout))
        with self._cond:
            self._abandoned = True  # a thread still held in a put publishes nothing after it
            left = list(self._items)
            if self._thread.is_alive():  # held in a put: the batch's rest is left too
                left += self._batch[self._next + 1 :]
                del self._batch[self._next + 1 :]
            self._items.clear()
            for item in left:
                self._done(item)
            n, stream = self._unlogged + len(left), self._last_dropped
            self._unlogged = 0
        if left:
            self._metrics.error_notices_dropped.inc(len(left))
        if n:
            self._log((n, stream), at_stop=True)

    # ------------------------------------------------------------------ the thread
    def _run(self) -> None:
        while True:
            with self._cond:  # all that waits, at once: one lock for a flood's many notices
                while not self._items and not self._closing:
                    self._cond.wait()
                if not self._items:
                    return
                batch = list(self._items)
                self._items.clear()
            self._batch = batch
            for i, (key, payload, _, _) in enumerate(batch):
                with self._cond:
                    if self._abandoned:  # the stop's deadline passed: close() counted the rest
                        break
                    self._next = i
                try:
                    put(self._session, key, payload, self._congestion)
                except zenoh.ZError as e:
                    log.error("error_publish_failed", key=key, error=str(e))
            with self._cond:
                for item in batch:
                    self._done(item)

    # ------------------------------------------------------------------ under the lock
    def _push(self, item: _Item) -> None:
        self._items.append(item)
        self._bytes += item[3]
        stream = item[2]
        self._pending[stream] = self._pending.get(stream, 0) + 1
        if len(self._items) == 1:
            self._cond.notify()

    def _done(self, item: _Item) -> None:
        """An item published (or given up): its bytes back, its stream's count down."""
        self._bytes -= item[3]
        stream = item[2]
        n = self._pending.get(stream, 0) - 1
        if n > 0:
            self._pending[stream] = n
        else:
            self._pending.pop(stream, None)

    def _dropped(self, stream: Stream) -> tuple[int, Stream | None] | None:
        self._unlogged += 1
        self._last_dropped = stream
        return self._due()

    def _due(self) -> tuple[int, Stream | None] | None:
        now = self._clock()
        if not self._unlogged or now < self._next_log:
            return None
        out = (self._unlogged, self._last_dropped)
        self._unlogged = 0
        self._next_log = now + self._log_interval_s
        return out

    def _log(self, logged: tuple[int, Stream | None] | None, at_stop: bool = False) -> None:
        if logged is None:
            return
        n, stream = logged
        vehicle, sensor = stream if stream is not None else (None, None)
        log.warning(
            "error_notices_dropped",
            dropped=n,
            vehicle=vehicle,
            sensor=sensor,
            waiting=len(self._items),
            **({"at": "stop"} if at_stop else {}),
        )


__all__ = ["ANNOUNCE_BYTES", "Announcer"]
