"""Which track messages a subscriber delivers, per stream (a tracks key: one sensor's, or one
fused vehicle's ``@vehicle``): not a message of a fenced holder, whose custody ``epoch`` is
below the highest the stream has shown (schemas/README.md, "Custody epoch (fencing)"), and
not an exact repeat of a recent (``seq``, ``stamp_ns``). One filter serves both subscribers.
"""

from __future__ import annotations

import threading
from collections import deque
from dataclasses import dataclass
from enum import Enum

RECENT_FRAMES = 16  # per key: a duplicate comes within a takeover, a few frames at most
MAX_KEYS = 100_000


class Verdict(Enum):
    DELIVER = "deliver"
    REPEAT = "repeat"  # (seq, stamp_ns) delivered on this stream within the window
    STALE = "stale"  # an epoch below the stream's highest: sent by a fenced holder


@dataclass(slots=True)
class _Stream:
    recent: deque[tuple[int, int]]  # (stamp_ns, seq) delivered, the last one last
    epoch: int | None = None  # the highest seen; None until a message carries one
    # A new holder replays from the last frame it heard, which may be many frames behind
    # (a partition lasts a lease at least): its messages up to the last one delivered from
    # the holder before are repeats, whatever the window holds. By (stamp, seq): a fused
    # vehicle's lidar and camera frames can share a stamp, each its own message. None:
    # caught up.
    handover: tuple[int, int] | None = None


class StreamFilter:
    """Thread-safe: samples of two members arrive on two links' threads, so each verdict
    and what it records are one step. Bounded: past ``max_keys`` streams it starts afresh
    (a stream forgotten so takes its next epoch as its highest). ``repeats`` and ``stale``
    count the messages refused for each reason."""

    def __init__(self, recent_frames: int = RECENT_FRAMES, max_keys: int = MAX_KEYS) -> None:
        for name, value in (("recent_frames", recent_frames), ("max_keys", max_keys)):
            if type(value) is not int or value < 1:
                raise ValueError(f"StreamFilter {name} must be an int >= 1, got {value!r}")
        self.recent_frames = recent_frames
        self.max_keys = max_keys
        self.repeats = 0
        self.stale = 0
        self._streams: dict[str, _Stream] = {}
        self._lock = threading.Lock()

    def admit(self, key: str, seq: int, stamp_ns: int, epoch: int | None) -> Verdict:
        """The verdict on a message of stream ``key``; a delivered one is remembered. A
        message without an epoch (a service of before epochs) is judged as a repeat or not
        only, and leaves the stream's highest epoch as it was."""
        with self._lock:
            stream = self._streams.get(key)
            if stream is None:
                if len(self._streams) >= self.max_keys:
                    self._streams.clear()
                stream = self._streams[key] = _Stream(deque(maxlen=self.recent_frames))
            if epoch is not None:
                if stream.epoch is not None and epoch < stream.epoch:
                    self.stale += 1
                    return Verdict.STALE
                if stream.epoch is not None and epoch > stream.epoch:
                    stream.handover = stream.recent[-1] if stream.recent else None
                # Raised even by a repeat: a new holder may send again what the old one sent,
                # and is the holder all the same.
                stream.epoch = epoch
            caught_up = stream.handover is None or (stamp_ns, seq) > stream.handover
            if (stamp_ns, seq) in stream.recent or (epoch is not None and not caught_up):
                self.repeats += 1
                return Verdict.REPEAT
            stream.handover = None
            stream.recent.append((stamp_ns, seq))
            return Verdict.DELIVER

    def highest_epoch(self, key: str) -> int | None:
        """The highest epoch stream ``key`` has shown (None: none, or forgotten)."""
        with self._lock:
            stream = self._streams.get(key)
            return None if stream is None else stream.epoch
