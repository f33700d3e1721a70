"""The sensors being published, as a member hears them from liveliness tokens: each advanced
publisher's own token (``<detections key>/@adv/pub/...``) and the scouts' tokens standing for
plain publishers. Declared with the group's token subscriber, before the start's settle time:
the tokens out before a member starts reach it as the subscriber's history, asynchronously
(Zenoh's interest round trip, a router away), and a token heard only after the start settled
marks its sensor as new to the fleet, whose frames then all come from the vehicle's cache.
Declared any later, a loaded host could hear an old vehicle's token past that mark and track
seconds of its cached frames again.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable, Container, Iterable, Mapping
from typing import Any

import zenoh

from simpletrack.server.group import undeclare
from simpletrack.wire.keys import DETECTIONS, SERVICE_CHUNK, VEHICLE_STREAM, Keys

ADV_TOKENS = "@adv/pub/**"
# A sensor stays subscribed this long after its last token went: a router's outage takes
# every token with it, and the subscriber kept recovers the outage's frames from the
# vehicle's cache as a wide one does; a plain sensor's scout may have left (the next one
# announces it again at its next frame).
GRACE_S = 30.0


class NewSensors:
    """The sensors first published while this member runs (their first token came after the
    start settled) and not yet subscribed here. Such a sensor's subscription and takeover
    take all its vehicle's cache keeps, however late the subscription comes: nobody can have
    heard those frames, and a subscription delayed past any bound (a loaded member) must
    not lose them silently. A sensor found another member's, or stood by for without
    hearing its frames, leaves the set: a takeover of it later is the custody machine's (the checkpoint, the standby's
    frames, the cache for a gap), as for any other. No clock, no lock (its owner's)."""

    def __init__(self) -> None:
        self._known: set[str] = set()  # sensors ever published with a token while running
        self._new: set[str] = set()

    def token(self, sensor: str, *, running: bool, back: bool) -> None:
        """A publisher's token of ``sensor`` appeared; ``running``: after the start settled;
        ``back``: the sensor had lost every token (a router's outage), it is not new."""
        if running and not back and sensor not in self._known:
            self._new.add(sensor)
        self._known.add(sensor)

    def others(self, sensors: set[str]) -> None:
        """``sensors`` (with tokens) are not this member's to hear."""
        self._new -= sensors

    def take(self, sensor: str) -> bool:
        """Subscribing to ``sensor`` now: does the subscription take the whole cache?"""
        fresh = sensor in self._new
        self._new.discard(sensor)
        return fresh


def heartbeat_keys(
    tokens: Mapping[str, set[str]], subscribed: Iterable[str], plain: Container[str]
) -> set[str]:
    """The keys a member's session hears heartbeats on: the token keys of the sensors it
    holds an advanced subscription for (a publisher's heartbeats go out on its token's key)."""
    return {k for s in subscribed if s not in plain for k in tokens.get(s, ())}


def fresh_of(fresh: Iterable[str], stream: str) -> set[str]:
    """Of the sensors ``fresh`` (``vehicle/sensor``), those whose frames go to ``stream``: the
    sensor's own, or every sensor of a fused vehicle's stream (``vehicle/@vehicle``)."""
    vehicle, name = stream.split("/", 1)
    if name != VEHICLE_STREAM:
        return {stream} & set(fresh)
    return {s for s in fresh if s.split("/", 1)[0] == vehicle}


def _seen(
    tokens: dict[str, set[str]], lost: dict[str, float], sensor: str, key: str, up: bool
) -> bool:
    """A token ``key`` of ``sensor`` appeared (``up``) or went: the sensor's last one gone
    is noted in ``lost``. Returns whether an appearing token ends such a loss (under the
    caller's lock)."""
    held = tokens.setdefault(sensor, set())
    if up:
        held.add(key)
        return lost.pop(sensor, None) is not None
    held.discard(key)
    if not held:
        del tokens[sensor]
        lost[sensor] = time.monotonic()
    return False


class SensorTokens:
    """The advanced publishers' tokens (per sensor) and the scouts' plain tokens, with when
    each sensor's last token went (it counts as published ``grace_s`` after)."""

    def __init__(self, session: zenoh.Session, keys: Keys, *, grace_s: float = GRACE_S) -> None:
        self.session, self.keys, self._grace_s = session, keys, grace_s
        self._lock = threading.Lock()
        self._tokens: dict[str, set[str]] = {}  # vehicle/sensor -> its publishers' tokens
        self._plain: dict[str, set[str]] = {}  # vehicle/sensor -> scouts' plain tokens
        self._adv_lost: dict[str, float] = {}  # sensor -> when its vehicle's last token went
        self._plain_lost: dict[str, float] = {}  # sensor -> when its scouts' last token went
        self._new = NewSensors()
        self._fresh: set[str] = set()  # subscribed as new, their stream not yet taken over
        self._running = False  # the start settled: tokens heard from now on may be new
        self.on_change: Callable[[], None] = lambda: None
        self._subs: list[Any] = []

    def start(self, *, plain: bool) -> None:
        """Hear the tokens (``plain``: the scouts' too), the ones out already first."""
        lv = self.session.liveliness()
        self._subs.append(
            lv.declare_subscriber(
                f"{self.keys.prefix}/*/*/{DETECTIONS}/{ADV_TOKENS}", self._on_token, history=True
            )
        )
        if plain:
            self._subs.append(
                lv.declare_subscriber(self.keys.plain(), self._on_plain_token, history=True)
            )

    def running(self) -> None:
        """The start settled: a sensor whose first token comes from now on is new."""
        with self._lock:
            self._running = True

    def _on_token(self, sample: zenoh.Sample) -> None:
        key = str(sample.key_expr)
        names = self.keys.sensor_of(key.split(f"/{DETECTIONS}/", 1)[0] + f"/{DETECTIONS}")
        if names is None:
            return
        sensor = f"{names[0]}/{names[1]}"
        up = sample.kind == zenoh.SampleKind.PUT
        with self._lock:
            back = _seen(self._tokens, self._adv_lost, sensor, key, up)
            if up:
                self._new.token(sensor, running=self._running, back=back)
        self.on_change()

    def _on_plain_token(self, sample: zenoh.Sample) -> None:
        key = str(sample.key_expr)
        names = self.keys.service_sensor_of(key)
        if names is None:
            return
        sensor = f"{names[0]}/{names[1]}"
        with self._lock:
            _seen(self._plain, self._plain_lost, sensor, key, sample.kind == zenoh.SampleKind.PUT)
        self.on_change()

    def tokened(self, sensor: str) -> bool:
        """Has a vehicle's token (or had, a moment ago: a router's outage)? Dict reads,
        atomic: no lock, for the scout's path."""
        return sensor in self._tokens or sensor in self._adv_lost

    def scouts_of(self, sensor: str) -> list[str]:
        """The members whose plain token names ``sensor`` (the scouts that kept its frames)."""
        with self._lock:
            keys = list(self._plain.get(sensor, ()))
        head = f"{self.keys.prefix}/{SERVICE_CHUNK}/"
        return sorted({k[len(head) :].split("/", 1)[0] for k in keys})

    def published(self) -> tuple[set[str], set[str]]:
        """(sensors with a vehicle's token, sensors found by a scout): those published."""
        now = time.monotonic()
        with self._lock:
            for lost in (self._adv_lost, self._plain_lost):
                for sensor in [s for s, t in lost.items() if now - t > self._grace_s]:
                    del lost[sensor]
            tokened = set(self._tokens) | set(self._adv_lost)
            plain = (set(self._plain) | set(self._plain_lost)) - tokened
        return tokened, plain

    def not_new(self, sensors: set[str]) -> None:
        """``sensors`` are not this member's to hear: none is new to it any more."""
        with self._lock:
            self._new.others(sensors)

    def take_new(self, sensor: str) -> bool:
        """Subscribing to ``sensor`` now: is it new to the fleet (its subscription takes the
        whole cache, and so does its stream's takeover, ``claim_fresh``)?"""
        with self._lock:
            fresh = self._new.take(sensor)
            if fresh:
                self._fresh.add(sensor)
            return fresh

    def unsubscribed(self, sensor: str) -> None:
        with self._lock:
            self._fresh.discard(sensor)

    def claim_fresh(self, stream: str) -> frozenset[str]:
        """A takeover of ``stream`` (a sensor's, or a fused vehicle's: ``v/@vehicle``): the
        names of its sensors subscribed as new since, each claimed once."""
        with self._lock:
            mine = fresh_of(self._fresh, stream) if self._fresh else set()
            self._fresh -= mine
        return frozenset(s.split("/", 1)[1] for s in mine)

    def heartbeat_keys(self, subscribed: Iterable[str], plain: Container[str]) -> set[str]:
        with self._lock:
            return heartbeat_keys(self._tokens, subscribed, plain)

    def close(self) -> None:
        undeclare(*self._subs)
        self._subs.clear()


__all__ = ["ADV_TOKENS", "GRACE_S", "NewSensors", "SensorTokens", "fresh_of", "heartbeat_keys"]
