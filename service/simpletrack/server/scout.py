"""The group's scout (``subscribe = "owned"``): one member hears every detection frame so that
sensors published by plain puts, which hold no advanced publisher's token, are found too.

The scout is the first member by name (every member computes it from its own view, so two
may scout for a moment while views settle: harmless, their tokens and frames agree). It keeps
one plain subscriber on ``<prefix>/*/*/detections``; a frame of a sensor with a token costs it
a key parse and a set lookup, nothing else. A frame of any other sensor is a plain publisher's:
the scout declares the liveliness token ``<prefix>/@simpletrack/<scout>/plain/<v>/<s>`` (the
owner and the standby subscribe to that sensor on seeing it, as on a vehicle's own token) and
keeps the sensor's last frames, which it answers on the same key: the owner asks for them once
its subscription is up, so the frames sent before that (the first one, at least) are tracked,
not lost. A plain sensor silent for ``idle_s`` is forgotten (token and frames).

The Zenoh callback only records; declarations happen on the subscriptions thread
(``reconcile``), never in a Zenoh callback.
"""

from __future__ import annotations

import threading
import time
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import zenoh

from simpletrack.server.group import undeclare
from simpletrack.server.logs import get_logger
from simpletrack.wire.keys import Keys

log = get_logger("group")
# What the scout keeps of a plain sensor's frames until its owner has asked for them (it
# subscribes within milliseconds of the token, but a vehicle's first burst can be long);
# frames pushed out of it unasked are announced as missed.
FIRST_BYTES = 8 << 20
TAKEN_BYTES = 1 << 20  # of a sensor this member takes in itself: only a standby may ask
ALL_BYTES = 256 << 20  # of every plain sensor together; past it each keeps its last frame
GATHER_S = 0.03  # a plain sensor is announced this long after its first frame
ASK_WINDOW_S = 2.0  # after the first question, the standby's comes within this
UNASKED_S = 5.0  # nobody asked this long after the first frame: what is kept is lost


@dataclass(slots=True)
class Kept:
    """A plain sensor's frames kept by the scout, each with when it was heard (wall ns)."""

    first_heard: float  # monotonic
    last_heard: float  # monotonic: silent idle_s, the sensor is forgotten
    frames: deque[tuple[int, bytes]] = field(default_factory=deque)
    nbytes: int = 0
    asked: float | None = None  # the first question (monotonic)
    last_only: bool = False  # asked long enough ago: the last frame is all a later asker gets
    taken: bool = False  # this member took its frames in itself (it owns or stands by for it)
    lost: int = 0  # pushed out before anyone asked, not announced yet

    def add(self, heard_ns: int, payload: bytes, cap: int) -> int:
        """Keep a frame within ``cap`` bytes; returns the change in bytes kept."""
        before = self.nbytes
        self.frames.append((heard_ns, payload))
        self.nbytes += len(payload)
        while len(self.frames) > 1 and (self.last_only or self.nbytes > cap):
            self.nbytes -= len(self.frames.popleft()[1])
            if self.asked is None and not self.taken:
                self.lost += 1
        return self.nbytes - before

    def settle(self, now: float) -> None:
        """Keep the last frame only, once the first askers had their time (or none came)."""
        asked_long_ago = self.asked is not None and now - self.asked > ASK_WINDOW_S
        unasked = self.asked is None and now - self.first_heard > UNASKED_S
        if not self.last_only and (asked_long_ago or unasked):
            self.last_only = True
            while len(self.frames) > 1:
                self.nbytes -= len(self.frames.popleft()[1])
                if unasked and not self.taken:
                    self.lost += 1


class Scout:
    def __init__(
        self,
        session: zenoh.Session,
        keys: Keys,
        instance: str,
        tokened: Callable[[str], bool],
        direct: Callable[[str, zenoh.Sample], bool],
        idle_s: float,
        wake: Callable[[], None],
        on_lost: Callable[[str, str, int], None],
    ) -> None:
        self.session, self.keys, self.instance = session, keys, instance
        self._tokened, self._direct, self._idle_s, self._wake = tokened, direct, idle_s, wake
        self._on_lost = on_lost
        self._lock = threading.Lock()
        self._frames: dict[str, Kept] = {}  # plain sensor -> its frames kept
        self._nbytes = 0  # kept of all of them
        self._tokens: dict[str, Any] = {}  # plain sensor -> its token, declared here
        self._entities: tuple[Any, ...] = ()  # subscriber, queryable while scouting

    @property
    def active(self) -> bool:
        return bool(self._entities)

    @property
    def plain(self) -> int:
        """Plain sensors this member announced (a metric)."""
        return len(self._tokens)

    def set_active(self, active: bool) -> dict[str, list[bytes]]:
        """Scout, or stop (the subscriptions thread, on a change of the members); stopping
        returns the frames kept of each plain sensor (the last ones this member took in by
        ``direct``, if it has a role for it)."""
        if active == self.active:
            return {}
        if active:
            self._entities = (
                # On Zenoh's own thread, as the intake's: a thread hop of its own would let
                # the scout fall behind the owners' subscribers it must keep up with.
                self.session.declare_subscriber(
                    self.keys.all_detections,
                    zenoh.handlers.Callback(self._on_frame, indirect=False),
                ),
                self.session.declare_queryable(self.keys.plain(self.instance), self._on_query),
            )
            log.info("scout_started", instance=self.instance)
            return {}
        undeclare(*self._entities)
        self._entities = ()
        with self._lock:
            tokens = list(self._tokens.values())
            kept = {s: [p for _, p in k.frames] for s, k in self._frames.items()}
            self._tokens.clear()
            self._frames.clear()
            self._nbytes = 0
        undeclare(*tokens)
        log.info("scout_stopped", instance=self.instance)
        return kept

    def _on_frame(self, sample: zenoh.Sample) -> None:
        """Zenoh callback, every frame of the fleet while scouting: cheap unless plain."""
        key = str(sample.key_expr)
        names = self.keys.sensor_of(key)
        if names is None:
            return
        sensor = f"{names[0]}/{names[1]}"
        if self._tokened(sensor) or sample.source_info is not None:
            # A vehicle's own token names it, or will: an advanced publisher's samples carry
            # their source (sequence numbers), a plain put's none. Its owner subscribes by
            # the token and takes the vehicle's cache of what came before.
            return
        payload = sample.payload.to_bytes()
        # A plain sensor this member owns or stands by for is taken in here, as a wide
        # member does: no subscription of its own, no delay, the fleet's order kept.
        taken = self._direct(sensor, sample)
        now = time.monotonic()
        with self._lock:
            kept = self._frames.get(sensor)
            fresh = kept is None
            if kept is None:
                kept = self._frames[sensor] = Kept(now, now)
            kept.taken, kept.last_heard = taken, now
            cap = 0 if self._nbytes > ALL_BYTES else TAKEN_BYTES if taken else FIRST_BYTES
            self._nbytes += kept.add(time.time_ns(), payload, cap)
        if fresh:
            self._wake()

    def _on_query(self, query: zenoh.Query) -> None:
        """An owner's or standby's question: the frames kept of one plain sensor, in order."""
        names = self.keys.service_sensor_of(str(query.key_expr))
        if names is None:
            return
        sensor = f"{names[0]}/{names[1]}"
        with self._lock:
            kept = self._frames.get(sensor)
            frames = [] if kept is None else list(kept.frames)
            if kept is not None and kept.asked is None:
                kept.asked = time.monotonic()
        for heard_ns, payload in frames:
            query.reply(query.key_expr, payload, attachment=heard_ns.to_bytes(8, "little"))

    def reconcile(self, now: float | None = None) -> float | None:
        """Tokens for the plain sensors found since, none for those silent ``idle_s``; the
        seconds until the next one is due, if one waits."""
        now = time.monotonic() if now is None else now
        with self._lock:
            silent = [s for s, k in self._frames.items() if now - k.last_heard > self._idle_s]
            for sensor in silent:
                self._nbytes -= self._frames.pop(sensor).nbytes
            gone = [self._tokens.pop(s) for s in silent if s in self._tokens]
            # A vehicle's sensors start together: announced together, their first frames go
            # to their owner in one batch, in the order heard.
            new = [
                s
                for s, kept in self._frames.items()
                if s not in self._tokens and now - kept.first_heard >= GATHER_S
            ]
            waiting = [
                GATHER_S - (now - kept.first_heard)
                for s, kept in self._frames.items()
                if s not in self._tokens and now - kept.first_heard < GATHER_S
            ]
            lost: dict[str, int] = {}
            for sensor, kept in self._frames.items():
                was = kept.nbytes
                kept.settle(now)  # a later subscriber gets the last frame, as from a cache of one
                self._nbytes += kept.nbytes - was
                if kept.lost:
                    lost[sensor], kept.lost = kept.lost, 0
        undeclare(*gone)
        for sensor, n in lost.items():
            vehicle, name = sensor.split("/")
            self._on_lost(vehicle, name, n)
        for sensor in new:
            vehicle, name = sensor.split("/")
            token = self.session.liveliness().declare_token(
                self.keys.plain(self.instance, vehicle, name)
            )
            with self._lock:
                self._tokens[sensor] = token
            log.info("plain_sensor_found", vehicle=vehicle, sensor=name, scout=self.instance)
        return min(waiting, default=None)

    def close(self) -> None:
        self.set_active(False)


def fetch_plain(
    session: zenoh.Session, keys: Keys, scouts: list[str], sensor: str
) -> list[tuple[int, bytes]]:
    """The frames a scout kept of a plain sensor, in its order, with when each was heard (of
    several scouts, for a moment while views settle, the one that kept most)."""
    vehicle, name = sensor.split("/")
    out: list[tuple[int, bytes]] = []
    for scout in scouts:
        try:
            # Every reply has the same key: the default consolidation would keep one.
            replies = list(
                session.get(
                    keys.plain(scout, vehicle, name),
                    timeout=1.0,
                    consolidation=zenoh.ConsolidationMode.NONE,
                )
            )
        except zenoh.ZError as e:
            log.warning("plain_fetch_failed", sensor=sensor, scout=scout, error=str(e))
            continue
        kept = []
        for reply in replies:
            if reply.ok is None:
                continue
            attachment = reply.ok.attachment
            heard_ns = int.from_bytes(attachment.to_bytes(), "little") if attachment else 0
            kept.append((heard_ns, reply.ok.payload.to_bytes()))
        if len(kept) > len(out):
            out = kept
    return out


__all__ = ["Scout", "fetch_plain"]
