"""Per-sensor subscriptions (``subscribe = "owned"``): a member subscribes only to the
sensors it owns or stands by for, found from the vehicles' own liveliness tokens, so that
its inbound traffic is its share of the fleet instead of all of it.

A ``DetectionPublisher`` (an advanced publisher with publisher detection) holds the token
``<detections key>/@adv/pub/<zid>/<eid>/...`` while it lives; a liveliness subscriber on
``<prefix>/*/*/detections/@adv/pub/**`` therefore lists the sensors being published
(server/sensor_tokens.py, declared before the start's settle time). A
publisher without that token (a plain ``put``) is found by the group's scout
(server/scout.py), whose token ``<prefix>/@simpletrack/<scout>/plain/<v>/<s>`` stands for it:
such a sensor gets a plain subscriber whose first frames wait until the scout's copies of the
frames sent before it (the first, at least) are fetched and put ahead of them.

A standby (``standby = "checkpoints"``, the default) does not subscribe to the frames of an
advanced publisher's sensor: it has the owner's checkpoints, and the vehicle's cache keeps the
frames since. Once it owns the sensor it subscribes as any new owner does, and the frames the
checkpoint lacks come from the cache (the history, then the takeover's fetch of the gap). A
plain sensor, whose publisher keeps no cache, is heard by its standby too, and so is a sensor
its vehicle will fuse once the whole group can (``fuses_later``, a rolling upgrade): the
copies kept of its own stream are the vehicle's first frames when the gate opens.

The tracks of the streams owned are heard per stream (an owner hears whether another member
took its stream over), from other sessions only: a member's own tracks teach it nothing. A
stream's standby, a fused vehicle's too, is told how far planners have it by its owner
(server/told.py), not by its tracks, unless it is a sensor whose vehicle fuses once the
whole group can (a member of before fusion tells nothing).

A publisher's heartbeats (``<detections key>/@adv/pub/<zid>/<eid>/...``, its token's key) reach
a session through the advanced subscriber's wildcard ``<detections key>/@adv/pub/**``, which
Zenoh delivers by testing the heartbeat's key against every subscriber of the session: a
member holding S sensors paid O(S) per heartbeat, O(S²) a second (docs/BENCHMARKS.md). Each
subscribed sensor's token keys are therefore declared as key expressions on the session: a
heartbeat then arrives by that declared id and goes to the subscribers matched once, at the
declaration. The same holds for the checkpoints an owner sends this member as a standby (heard
by the wildcard ``<prefix>/@simpletrack/<me>/checkpoint/*/...``): each held stream's own
checkpoint key is declared too.

Declarations happen on this module's own thread, never in a Zenoh callback.
"""

from __future__ import annotations

import heapq
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import zenoh
from zenoh import ext

from simpletrack.server.group import Membership, Role, on_zenoh, undeclare
from simpletrack.server.intake import Intake
from simpletrack.server.logs import get_logger
from simpletrack.server.scout import GATHER_S, Scout, fetch_plain
from simpletrack.server.sensor_tokens import SensorTokens
from simpletrack.wire.keys import VEHICLE_STREAM, Keys

log = get_logger("group")
# A plain sensor's gate opens once the scout's copies meet the frames heard here (no frame
# between them), or after QUIET_S without a frame here; at the latest after VERIFY_S.
QUIET_S, VERIFY_S, RETRY_S = 0.05, 2.0, 0.01


class DeclaredKey:
    """A key expression declared on a session, undeclared like the other entities."""

    def __init__(self, session: zenoh.Session, key: str) -> None:
        self._session = session
        self.key_expr = session.declare_keyexpr(key)

    def undeclare(self) -> None:
        self._session.undeclare(self.key_expr)


@dataclass(frozen=True, slots=True)
class TracksHandlers:
    """Who hears the tracks of a sensor stream and of a fused vehicle's stream."""

    sensor: Callable[[zenoh.Sample], None]
    vehicle: Callable[[zenoh.Sample], None]


class _Held:
    """A plain sensor's subscriber callback: the first frames wait until the scout's copies
    of earlier ones are in, then each frame goes on once, in the order heard."""

    def __init__(self, deliver: Callable[[zenoh.Sample], None]) -> None:
        self._deliver = deliver
        self.lock = threading.Lock()
        self.held: list[tuple[int, str, bytes]] | None = []  # (wall ns, key, payload)

    def __call__(self, sample: zenoh.Sample) -> None:
        with self.lock:
            if self.held is not None:
                self.held.append((time.time_ns(), str(sample.key_expr), sample.payload.to_bytes()))
                return
        self._deliver(sample)


def before(earlier: list[bytes], heard: list[bytes]) -> int | None:
    """How many of the scout's frames (``earlier``, in its order) came before the first one
    heard here, or None if the two lists do not meet. Frames are told apart by their bytes
    only, so the two must agree frame by frame where they overlap; of the places where they
    do, the latest (a vehicle that sends a frame twice is then answered twice)."""
    for i in range(len(earlier) - 1, -1, -1):
        n = min(len(earlier) - i, len(heard))
        if earlier[i : i + n] == heard[:n]:
            return i
    return None


def met(held: _Held, earlier: list[tuple[int, bytes]], waited_s: float) -> bool:
    """The scout's copies reach a frame heard here (the scout hears a publisher's frames in
    the order this subscriber does, on its own thread, maybe behind it: then it has every
    frame before that one); or nothing was heard here for QUIET_S, long enough for the
    scout's backlog to be through."""
    with held.lock:
        heard = [payload for _, _, payload in held.held or ()]
    if not heard:
        return waited_s > QUIET_S
    return before([p for _, p in earlier], heard) is not None


def skip_taken(held: _Held, taken: list[bytes]) -> None:
    """Drop the held frames the scout's own subscriber took in too (the longest run at the
    head of those held that ends what it took in)."""
    with held.lock:
        mine = held.held or []
        heard = [p for _, _, p in mine]
        for k in range(min(len(taken), len(heard)), 0, -1):
            if taken[-k:] == heard[:k]:
                held.held = mine[k:]
                return


def release(
    batch: list[tuple[_Held, str, list[tuple[int, bytes]]]], inject: Callable[[str, bytes], None]
) -> list[int]:
    """Open the gates of plain sensors subscribed together: of each sensor, the scouts' frames
    sent before the subscription (in the scout's order), then those held;
    the sensors' frames interleaved by when they were heard (a fused vehicle's sensors keep
    their order); then live frames pass. Returns each one's count of frames from the scouts."""
    for held, _, _ in batch:
        held.lock.acquire()
    try:
        streams: list[list[tuple[int, str, bytes]]] = []
        extras = []
        for held, key, earlier in batch:
            mine = held.held or []
            # The frames before the subscription: the scout's up to the first heard here
            # (later ones are here already, or on their way here).
            n = before([p for _, p in earlier], [p for _, _, p in mine]) if mine else None
            extra = [(t, key, p) for t, p in earlier[: len(earlier) if n is None else n]]
            extras.append(len(extra))
            streams.append(extra + mine)
            held.held = None
        # heapq.merge keeps each sensor's own order whatever its clocks say.
        for _, key, payload in heapq.merge(*streams, key=lambda f: f[0]):
            inject(key, payload)
        return extras
    finally:
        for held, _, _ in batch:
            held.lock.release()


def hears_frames(role: Role, *, cached: bool, fuses_later: bool, standby_frames: bool) -> bool:
    """Whether a member subscribes to a sensor's frames: its owner always; its standby only
    when the frames cannot come from elsewhere at a takeover (no vehicle's cache: a plain
    put), when its vehicle will fuse once the whole group can (a rolling upgrade: its own
    stream's frames kept are the vehicle's first when the gate opens), or when told to
    (``standby = "frames"``); nobody else."""
    if role is Role.NONE:
        return False
    return role is Role.OWNER or standby_frames or not cached or fuses_later


def hears_tracks(role: Role, *, fuses_later: bool) -> bool:
    """Whether a member subscribes to a stream's tracks key: its owner (another member's
    message there fences its state); a sensor's standby only while its vehicle waits to
    fuse (a member of before fusion tells nothing); else, a stream's owner tells its
    standby, a fused vehicle's too (server/told.py)."""
    if role is Role.NONE:
        return False
    return role is Role.OWNER or fuses_later


class Subscriptions:
    def __init__(
        self,
        session: zenoh.Session,
        keys: Keys,
        membership: Membership,
        tokens: SensorTokens,
        handler: Callable[[], Any],
        on_miss: Callable[[ext.Miss], None],
        history_frames: int,
        stream_of: Callable[[str, str], str] = lambda v, s: f"{v}/{s}",
        *,
        tracks: TracksHandlers | None = None,
        intake: Intake | None = None,
        on_lost: Callable[[str, str, int], None] | None = None,
        idle_s: float = 60.0,
        standby_frames: bool = False,
        fuses_later: Callable[[str, str], bool] = lambda v, s: False,
    ) -> None:
        """``standby_frames``: a standby hears an advanced publisher's frames too;
        ``fuses_later``: whether a sensor is one its vehicle fuses once the whole group can
        (heard by its standby until then)."""
        self.session, self.keys, self.membership = session, keys, membership
        self._standby_frames, self._fuses_later = standby_frames, fuses_later
        self._handler, self._on_miss, self._history = handler, on_miss, history_frames
        self._stream_of = stream_of  # a fused sensor's role is its vehicle's
        self._tracks, self._intake = tracks, intake  # intake: plain sensors heard (a scout)
        self.tokens = tokens  # started by the caller, before the start's settle time
        tokens.on_change = self.changed
        self._subs: dict[str, tuple[Any, ...]] = {}  # vehicle/sensor -> its entities
        self._plain_subs: set[str] = set()  # the sensors of _subs subscribed as plain
        self._track_subs: dict[str, Any] = {}  # stream -> its tracks subscriber
        # Keys heard through a wildcard, declared (heartbeats, checkpoints): key -> entity.
        self._exact: dict[str, DeclaredKey] = {}
        self._wake = threading.Event()
        self._stop = threading.Event()
        self._idle = threading.Event()
        self._thread = threading.Thread(target=self._run, name="subscriptions", daemon=True)
        self.scout = (
            Scout(
                session,
                keys,
                membership.me,
                tokens.tokened,
                self._direct,
                idle_s,
                self.changed,
                on_lost,
            )
            if intake is not None and on_lost is not None
            else None
        )

    @property
    def subscribed(self) -> int:
        return len(self._subs)

    @property
    def exact_keys(self) -> frozenset[str]:
        """The keys heard through a wildcard that this member declared on its session."""
        return frozenset(self._exact)

    def start(self) -> None:
        self._thread.start()

    def _direct(self, sensor: str, sample: zenoh.Sample) -> bool:
        """The scout's frame of a plain sensor: taken in when this member has a role for it
        and no subscription of its own (it had one before it became the scout)."""
        if self._intake is None or sensor in self._subs:
            return False
        vehicle, name = sensor.split("/")
        if self.membership.role(self._stream_of(vehicle, name)) is Role.NONE:
            return False
        self._intake(sample)
        return True

    def changed(self) -> None:
        """The membership changed: roles, hence the wanted sensors, may have."""
        self._idle.clear()
        self._wake.set()

    def settle(self, timeout: float) -> bool:
        """Wait until the subscriptions match the roles (at start, before the token)."""
        self.changed()
        done = self._idle.wait(timeout)
        self.tokens.running()
        return done

    def _wanted(self, published: set[str]) -> set[str]:
        """Of the sensors published, those this member owns or stands by for."""
        return {
            s
            for s in published
            if self.membership.role(self._stream_of(*s.split("/"))) is not Role.NONE
        }

    def _hears_frames(self, sensor: str, tokened: set[str]) -> bool:
        vehicle, name = sensor.split("/")
        return hears_frames(
            self.membership.role(self._stream_of(vehicle, name)),
            cached=sensor in tokened,
            fuses_later=self._fuses_later(vehicle, name),
            standby_frames=self._standby_frames,
        )

    def _hears_tracks(self, stream: str) -> bool:
        vehicle, name = stream.split("/")
        return hears_tracks(
            self.membership.role(stream), fuses_later=self._fuses_later(vehicle, name)
        )

    def _run(self) -> None:
        due: float | None = None
        while not self._stop.is_set():
            self._wake.wait(0.5 if due is None else min(0.5, due))
            self._wake.clear()
            if self._stop.is_set():
                break
            try:
                due = self._reconcile()
            except zenoh.ZError as e:
                log.warning("subscriptions_failed", error=str(e))
            if not self._wake.is_set():
                self._idle.set()

    def _reconcile(self) -> float | None:
        due = None
        scouting = was_scouting = False
        if self.scout is not None:
            scouting = min(self.membership.members) == self.membership.me
            was_scouting = self.scout.active
            if scouting:
                self.scout.set_active(True)
                due = self.scout.reconcile()
        tokened, plain = self.tokens.published()
        if not scouting and self._wanted(plain) - set(self._subs):
            # New plain sensors: their vehicle's others may be on their way (one batch).
            time.sleep(GATHER_S)
            tokened, plain = self.tokens.published()
        wanted = self._wanted(tokened | plain)
        heard = {s for s in wanted if self._hears_frames(s, tokened)}
        # Not heard here, a sensor is not new to this member any more: once it owns it
        # (a failover, a hand-off), its subscription takes ``history_frames`` and the
        # takeover fetches just the gap after its state, in one piece, beside the queue
        # (a whole cache per sensor through the queues at once shed the survivors' own
        # frames: 500 sensors, 228 moved, 23-55 refused).
        self.tokens.not_new(tokened - heard)
        # A plain sensor whose vehicle now holds a token is subscribed again, advanced.
        changed = {s for s in self._plain_subs if s in tokened}
        for sensor in [s for s in self._subs if s not in heard or s in changed]:
            undeclare(*self._subs.pop(sensor))
            self.tokens.unsubscribed(sensor)
            self._plain_subs.discard(sensor)
        plain_batch: list[tuple[str, _Held]] = []
        for sensor in sorted(heard - set(self._subs)):
            if sensor in tokened:
                self._subs[sensor] = self._advanced(sensor)
            elif not scouting:  # the scout takes its plain sensors in directly
                sub, held = self._plain_subscriber(sensor)
                self._subs[sensor] = (sub,)
                self._plain_subs.add(sensor)
                plain_batch.append((sensor, held))
        taken: dict[str, list[bytes]] = {}
        if self.scout is not None and was_scouting and not scouting:
            taken = self.scout.set_active(False)  # after its sensors' own subscriptions
        if plain_batch:
            self._release_plain(plain_batch, taken)
        streams = {self._stream_of(*s.split("/")) for s in wanted}
        self._reconcile_tracks(streams)
        self._reconcile_exact(streams)
        return due

    def _reconcile_exact(self, streams: set[str]) -> None:
        me = self.membership.me
        keys = self.tokens.heartbeat_keys(self._subs, self._plain_subs)
        keys |= {self.keys.checkpoint(me, *stream.split("/")) for stream in streams}
        for key in [k for k in self._exact if k not in keys]:
            undeclare(self._exact.pop(key))
        for key in sorted(keys - set(self._exact)):
            self._exact[key] = DeclaredKey(self.session, key)

    def _advanced(self, sensor: str) -> tuple[Any, ...]:
        """A sensor its vehicle started publishing after this member started: nobody heard
        its frames before this subscription (a vehicle may start on the first subscriber it
        matches, the scout's), so its whole cache comes first; any other: its last
        ``history_frames`` (the custody machine skips what a state already holds). The
        whole history is not enough alone: zenoh-ext 1.10 can deliver a live frame ahead of
        a history still pending and then drop that history as old, unannounced (1 replay in
        ~40); the new sensor's takeover asks the cache for all it keeps too
        (``SensorTokens.claim_fresh``).

        Only a new sensor's subscription asks a publisher that appears later
        (``detect_late_publishers``: a router's outage over, its token back) for its cache,
        and then for all of it. zenoh-ext asks with the history's bound: cut to
        ``history_frames``, the outage's gap behind the frame answered was counted as
        missed. Without that question a gap is asked for exactly, by its first frame after
        the gap or by the publisher's next heartbeat."""
        vehicle, name = sensor.split("/")
        fresh = self.tokens.take_new(sensor)
        sub = ext.declare_advanced_subscriber(
            self.session,
            self.keys.detections(vehicle, name),
            self._handler(),
            history=ext.HistoryConfig(
                detect_late_publishers=fresh, max_samples=None if fresh else self._history
            ),
            recovery=ext.RecoveryConfig(heartbeat=True, periodic_queries=None),
        )
        return (sub.sample_miss_listener(on_zenoh(self._on_miss)), sub)

    def _plain_subscriber(self, sensor: str) -> tuple[Any, _Held]:
        """Its frames wait (``release``) until the scouts' copies of earlier ones are in."""
        intake = self._intake
        assert intake is not None
        vehicle, name = sensor.split("/")
        held = _Held(intake)
        sub = self.session.declare_subscriber(
            self.keys.detections(vehicle, name), intake.handler(held)
        )
        return sub, held

    def _release_plain(self, batch: list[tuple[str, _Held]], taken: dict[str, list[bytes]]) -> None:
        """Subscribed first, then the scouts asked: every frame is in one of the two (a
        frame in both goes on once). A sensor this member took in itself as the scout until
        now (``taken``: its last frames) skips what it took in twice and asks nobody."""
        assert self._intake is not None
        for sensor, held in batch:
            if sensor in taken:
                skip_taken(held, taken[sensor])
        start = time.monotonic()
        fetched: dict[str, list[tuple[int, bytes]]] = {s: [] for s, _ in batch if s in taken}
        pending = {s: h for s, h in batch if s not in taken}
        while pending:
            now = time.monotonic()
            for sensor, held in list(pending.items()):
                earlier = fetch_plain(
                    self.session, self.keys, self.tokens.scouts_of(sensor), sensor
                )
                if met(held, earlier, now - start):
                    fetched[sensor] = earlier
                    del pending[sensor]
                elif now - start > VERIFY_S:
                    fetched[sensor] = earlier
                    del pending[sensor]
                    log.warning("plain_sensor_unverified", sensor=sensor, waited_s=VERIFY_S)
            if pending:
                time.sleep(RETRY_S)
        gates = []
        for sensor, held in batch:
            vehicle, name = sensor.split("/")
            gates.append((held, self.keys.detections(vehicle, name), fetched[sensor]))
        extras = release(gates, self._intake.inject)
        for (sensor, _), extra in zip(batch, extras, strict=True):
            vehicle, name = sensor.split("/")
            log.info("plain_sensor_subscribed", vehicle=vehicle, sensor=name, from_scout=extra)

    def _reconcile_tracks(self, streams: set[str]) -> None:
        """The tracks of the streams owned here (another member's message there fences this
        one's state), and of the sensors stood by for that their vehicle fuses once the
        whole group can (a rolling upgrade: a member of before fusion tells nothing, and the
        vehicle's takeover skips what it answered); a stream's standby is told by its owner
        instead (server/told.py)."""
        if self._tracks is None:
            return
        streams = {s for s in streams if self._hears_tracks(s)}
        for stream in [s for s in self._track_subs if s not in streams]:
            undeclare(self._track_subs.pop(stream))
        for stream in sorted(streams - set(self._track_subs)):
            vehicle, name = stream.split("/")
            if name == VEHICLE_STREAM:
                key, handler = self.keys.vehicle_tracks(vehicle), self._tracks.vehicle
            else:
                key, handler = self.keys.tracks(vehicle, name), self._tracks.sensor
            self._track_subs[stream] = self.session.declare_subscriber(
                key,
                on_zenoh(handler),
                allowed_origin=zenoh.Locality.REMOTE,
            )

    def close(self) -> None:
        """Stop and undeclare everything (first thing at shutdown: no new frames)."""
        self._stop.set()
        self._wake.set()
        if self._thread.is_alive():
            self._thread.join(5)
        self.tokens.close()
        if self.scout is not None:
            self.scout.close()
        for entities in self._subs.values():
            undeclare(*entities)
        self._subs.clear()
        undeclare(*self._track_subs.values())
        self._track_subs.clear()
        undeclare(*self._exact.values())
        self._exact.clear()


__all__ = [
    "DeclaredKey",
    "Subscriptions",
    "TracksHandlers",
    "hears_frames",
    "hears_tracks",
]
