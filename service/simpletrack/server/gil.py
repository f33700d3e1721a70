"""The interpreter lock goes to the frames being tracked, not to a flood.

A thread that takes the interpreter lock for a moment per item, by the ten thousand a second,
holds it nearly all the time: Zenoh's thread of a flooding link (each sample is a call into
Python) lets it go between samples and takes it again before a waiting thread is even
scheduled. CPython gives the lock to whoever asks first once it is free, and a waiting thread
asks the holder to let go (after ``sys.getswitchinterval()``) only if no other switch happened
meanwhile, so against such a thread it never asks. A worker tracking a frame lets the lock go
at every large numpy call; during a flood's backlog it got it back only once the backlog was
read. Measured (2 shared cores, a 5 s garbage flood from another process, then a new
sensor's two 3000-box frames on the flood's worker; 6 runs each way): the second answered
after 0.89-1.35 s without the pause, 0.09-0.13 s with it; a calm 10 Hz sensor's worst frame
0.87-1.27 s against 0.02-0.08 s (docs/SERVICE.md, "Floods and link-mates").

So, while any worker tracks a frame, the threads serving a flood sleep ``PAUSE_S`` after each
item of it: Zenoh's thread after a sample that made its own lane shed a frame, a worker
before announcing a refusal, the status queryable before answering a query and the snapshot
queryable before refusing one as busy. The lock is free for that long, long enough for the
tracking thread to take it.
"""

from __future__ import annotations

import time
from types import TracebackType

# Long enough for a waiting thread to wake and take the lock (a sleep of 0.2 ms lasts ~0.28 ms
# here): while a worker tracks, a link whose samples shed their own lane is read at most
# ~3,500 samples a second. 0: no pause.
PAUSE_S = 0.0002


class Trackers:
    """Which workers are tracking a frame now: each writes only its own slot (no lock; a
    reader may see a slot a moment late, which costs at most one pause or one missed)."""

    def __init__(self, workers: int, pause_s: float = PAUSE_S) -> None:
        self._slots = [False] * workers
        self.pause_s = pause_s

    def tracking(self, index: int) -> _Tracking:
        """Worker ``index`` tracks a frame inside this block (nested blocks are fine)."""
        return _Tracking(self._slots, index)

    def busy(self) -> bool:
        return True in self._slots

    def pause(self, own: int | None = None) -> None:
        """Let a tracking worker have the interpreter lock, if one is tracking (other than
        worker ``own``: a worker refusing inside its own tracking needs no pause)."""
        tracking = self._slots.count(True)
        if tracking and self.pause_s and (own is None or tracking > self._slots[own]):
            time.sleep(self.pause_s)


class _Tracking:
    """The block of ``Trackers.tracking``: a plain context manager, not a generator's (a
    frame enters one or two; contextlib's costs ~1.5 us more each)."""

    __slots__ = ("_before", "_index", "_slots")

    def __init__(self, slots: list[bool], index: int) -> None:
        self._slots, self._index, self._before = slots, index, False

    def __enter__(self) -> None:
        self._before = self._slots[self._index]
        self._slots[self._index] = True

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        self._slots[self._index] = self._before


__all__ = ["PAUSE_S", "Trackers"]
