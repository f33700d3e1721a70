"""What an owner tells a stream's standby of the tracks messages it published: each one's
stamp, next id and epoch (a fused vehicle's: and its message seq), in batches on
``<prefix>/@simpletrack/<standby>/told``.

A standby needs of a stream's tracks only how far planners have them, the ids they hold and
the epoch (server/heard.py). Heard as the tracks themselves, the messages cost it ~0.15 ms a
frame, most of what a member pays for the sensors it does not own; told one ~60-byte message
per frame instead, about as much (docs/BENCHMARKS.md, "What each role costs per frame"): a
message's receive costs Zenoh a wake-up whatever its size. So the words wait in the worker
and go together, ``FLUSH_S`` after the first of them (sensors' frames come spread over their
period: a worker idle between two finds none waiting behind the first) or before a stream's
second word (a stream has at most one word unsaid). Each goes after its message, never before:
what the standby is told planners may have, they were sent. A failover from a killed or
stopped owner therefore publishes again the last frame it was told of, and the one after it
if that was put before its word went: at most two repeats per moved stream, which readers
drop (``TrackSubscriber``; docs/SCALE.md). A fused vehicle's words (six fields, its seq
the sixth) go in messages of their own: a member of before vehicle words, which refuses a
whole message for one word it cannot read, still learns its sensors' words (and hears the
vehicle's tracks itself).

The newest message of a stream, which a failover publishes again where the checkpoint holds
its frame (the dead owner may have put it on some links only), rides on the checkpoint, as
its attachment (server/custody.py ``_put_checkpoint``; a final checkpoint's is
``FINAL_CHECKPOINT``: its holder stopped with every message out).
"""

from __future__ import annotations

import contextlib
import re
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Protocol

import msgpack
import zenoh

from simpletrack.server.logs import get_logger
from simpletrack.wire.header import peek_heard, peek_vehicle_heard
from simpletrack.wire.keys import VEHICLE_STREAM, Keys
from simpletrack.wire.messages import NAME_PATTERN

__all__ = ["FLUSH_S", "Teller", "Told", "read_told", "told_payload"]

log = get_logger("group")
NAME_RE = re.compile(NAME_PATTERN)
MSGPACK = zenoh.Encoding("application/msgpack")
FLUSH_S = 0.05  # how long the first word waits for others (half a 10 Hz period)
MAX_WORDS = 10_000  # a message's words at most (a reader refuses more)
_INT64_MAX = 2**63 - 1

# vehicle, sensor, stamp_ns, next_id, epoch; a fused vehicle's (sensor VEHICLE_STREAM): seq
Word = tuple[str, str, int, int, int | None] | tuple[str, str, int, int, int | None, int]


@dataclass(frozen=True, slots=True)
class Told:
    """One tracks message an owner published: its stream's names and what a standby keeps."""

    vehicle: str
    sensor: str
    stamp_ns: int
    next_id: int
    epoch: int | None
    instance: str  # the owner that published it
    seq: int | None = None  # a fused vehicle's message seq (None: a sensor's word)

    @property
    def stream(self) -> str:
        return f"{self.vehicle}/{self.sensor}"


def word_of(vehicle: str, sensor: str, tracks: bytes) -> Word | None:
    """What to tell of the tracks message ``tracks`` (None: unreadable, nothing to tell); a
    fused vehicle's (``sensor`` VEHICLE_STREAM) is a VehicleTrackFrame, its seq told too."""
    if sensor == VEHICLE_STREAM:
        read = peek_vehicle_heard(tracks)
        if read is None:
            return None
        stamp, next_id, seq, epoch = read
        return vehicle, sensor, stamp, next_id, epoch, seq
    heard = peek_heard(tracks)
    if heard is None:
        return None
    stamp_ns, next_id, epoch = heard
    return vehicle, sensor, stamp_ns, next_id, epoch


def told_payload(words: list[Word], instance: str) -> bytes:
    packed: bytes = msgpack.packb([instance, words])
    return packed


def read_told(payload: bytes) -> list[Told] | None:
    """A told message's words, or None: anything malformed is ignored whole (it teaches
    nothing, and a standby that knows less only publishes again what planners had)."""
    try:
        obj = msgpack.unpackb(payload, raw=False)
    except Exception:
        return None
    if not isinstance(obj, list) or len(obj) != 2:
        return None
    instance, words = obj
    if not isinstance(instance, str) or not isinstance(words, list) or len(words) > MAX_WORDS:
        return None
    out: list[Told] = []
    for w in words:
        told = _told(w, instance)
        if told is None:
            return None
        out.append(told)
    return out


def _told(w: object, instance: str) -> Told | None:
    """A sensor's word (5 fields) or a fused vehicle's (6: its sensor VEHICLE_STREAM, its
    seq last); None for anything else."""
    if not isinstance(w, list) or len(w) not in (5, 6):
        return None
    vehicle, sensor, stamp_ns, next_id, epoch = w[:5]
    if not (isinstance(vehicle, str) and NAME_RE.fullmatch(vehicle) and isinstance(sensor, str)):
        return None
    seq = None
    if len(w) == 6:
        seq = w[5]
        if sensor != VEHICLE_STREAM or not _int64(seq):
            return None
    elif not NAME_RE.fullmatch(sensor):
        return None
    if not (_int64(stamp_ns) and _int64(next_id) and (epoch is None or _int64(epoch))):
        return None
    return Told(vehicle, sensor, stamp_ns, next_id, epoch, instance, seq)


def _int64(v: object) -> bool:
    return type(v) is int and 0 <= v <= _INT64_MAX


class Publishing(Protocol):
    """Where a worker publishes (its outbox's session and settings)."""

    session: zenoh.Session
    keys: Keys
    congestion: zenoh.CongestionControl
    instance: str


class Teller:
    """One worker's words to the standbys of the streams it publishes, a publisher per
    standby member (declared at its first message, kept: a member's standbys are the group's
    few other members). Only the worker uses it, under its lock."""

    def __init__(
        self,
        outbox: Publishing,
        standby_of: Callable[[str], str | None],
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        self.session, self.keys, self.congestion = outbox.session, outbox.keys, outbox.congestion
        self.instance, self.standby_of, self.clock = outbox.instance, standby_of, clock
        self._publishers: dict[str, zenoh.Publisher] = {}
        self._waiting: dict[str, tuple[str, Word]] = {}  # stream -> (its standby, its word)
        self._first_at = 0.0

    def _word(self, vehicle: str, sensor: str, tracks: bytes) -> tuple[str, Word] | None:
        """The stream's standby and the word of ``tracks`` (None: no standby, or nothing
        readable to tell)."""
        standby = self.standby_of(f"{vehicle}/{sensor}")
        if standby is None or standby == self.instance:
            return None
        word = word_of(vehicle, sensor, tracks)
        return None if word is None else (standby, word)

    def message(self, vehicle: str, sensor: str, tracks: bytes) -> tuple[str, bytes] | None:
        """(key, payload) telling the stream's standby of ``tracks`` at once (a message the
        announcer publishes, behind notices: its word goes after it); None: no standby."""
        told = self._word(vehicle, sensor, tracks)
        if told is None:
            return None
        standby, word = told
        return self.keys.told(standby), told_payload([word], self.instance)

    def published(self, vehicle: str, sensor: str, tracks: bytes) -> None:
        """``tracks`` went out: its word waits for the next flush (this stream's waiting
        word, if any, goes first)."""
        told = self._word(vehicle, sensor, tracks)
        if told is None:
            return
        stream = f"{vehicle}/{sensor}"
        if stream in self._waiting:
            self.flush()
        if not self._waiting:
            self._first_at = self.clock()
        self._waiting[stream] = told

    def due(self) -> bool:
        """The first word waiting has waited ``FLUSH_S``."""
        return bool(self._waiting) and self.clock() - self._first_at >= FLUSH_S

    def deadline(self) -> float | None:
        """When the words waiting are due (the clock's time; None: none waits)."""
        return self._first_at + FLUSH_S if self._waiting else None

    def flush(self) -> None:
        """One message per standby member, its streams' words in the order they waited (its
        fused vehicles' in one more: see the module's docstring)."""
        by_standby: dict[tuple[str, bool], list[Word]] = {}
        for standby, word in self._waiting.values():
            by_standby.setdefault((standby, len(word) == 6), []).append(word)
        self._waiting.clear()
        for (standby, _), words in by_standby.items():
            self.put(self.keys.told(standby), told_payload(words, self.instance))

    def put(self, key: str, payload: bytes) -> None:
        """Untold (the session closing), the standby thinks planners have less: a failover
        then publishes again what they had, never less. So a failure is only logged."""
        try:
            pub = self._publishers.get(key)
            if pub is None:
                if len(self._publishers) > 1024:  # members come and go: a bounded table
                    self._undeclare()
                pub = self._publishers[key] = self.session.declare_publisher(
                    key, encoding=MSGPACK, congestion_control=self.congestion
                )
            pub.put(payload)
        except zenoh.ZError as e:
            log.debug("told_failed", key=key, error=str(e))

    def close(self) -> None:
        self.flush()
        self._undeclare()

    def _undeclare(self) -> None:
        for pub in self._publishers.values():
            with contextlib.suppress(zenoh.ZError):  # the session already closed
                pub.undeclare()  # type: ignore[no-untyped-call]
        self._publishers.clear()
