"""A worker's side of the group protocol (docs/SCALE.md): which frames it tracks, keeps or
ignores; taking a sensor over (ask the holder, else the standby checkpoint, then replay);
releasing one to a member that asks; sending checkpoints to each sensor's standby.

Only the worker's thread calls it, except ``release`` after the workers have stopped.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

import zenoh

from simpletrack.server.group import Membership, Role
from simpletrack.server.intake import Inbound, stamp_of
from simpletrack.server.logs import get_logger
from simpletrack.server.metrics import Metrics
from simpletrack.server.outbox import MSGPACK, Outbox
from simpletrack.server.registry import SensorRegistry
from simpletrack.server.sensors import SensorState
from simpletrack.server.snapshots import ID_BLOCK
from simpletrack.server.standby import Standby
from simpletrack.server.vehicles import VehicleState
from simpletrack.wire.codec import DecodeLimits, Rejection, decode_message, encode
from simpletrack.wire.header import peek_header
from simpletrack.wire.keys import VEHICLE_STREAM, Keys
from simpletrack.wire.models import SensorSnapshot

log = get_logger("group")
# A sensor released to a member this one cannot see yet (its token is on the way) is not
# taken back for this long: the views agree well within it.
RELEASE_GUARD_S = 2.0
RELEASED_KEPT_S = 60.0
_SNAP_LIMITS = DecodeLimits(max_bytes=1 << 30, max_boxes=1 << 30)


@dataclass(frozen=True, slots=True)
class Released:
    snapshot: SensorSnapshot
    to: str
    at: float


@dataclass(slots=True)
class Takeover:
    """How a sensor came to this member: ``state`` None means a sensor nobody held."""

    vehicle: str
    sensor: str
    source: str  # "handoff", "failover", "restore", "lost" or "new"
    snapshot: SensorSnapshot | None  # the state taken over
    heard: Heard | None  # the last tracks planners got, from any member
    state: SensorState | None = None
    vehicle_state: VehicleState | None = None  # a fused vehicle's, instead of ``state``
    replay: list[Inbound] = field(default_factory=list)
    missed: int = 0  # frames after the state that neither the standby nor the vehicle kept
    from_cache: int = 0  # frames replayed from the vehicle's cache
    done: bool = False

    @property
    def covered_stamp_ns(self) -> int | None:
        """Frames up to it are in the state already."""
        return None if self.snapshot is None else self.snapshot.last_stamp_ns

    @property
    def published_stamp_ns(self) -> int | None:
        """Planners have tracks up to it. The holder of a hand-off published all it heard; a
        member killed mid-put may have written its last tracks to some links only (Zenoh
        writes one link after another), so after a failover the last frame heard is
        published again and ``TrackSubscriber`` drops the repeat where it arrived before."""
        if self.heard is None:
            return None
        return self.heard.stamp_ns if self.source == "handoff" else self.heard.stamp_ns - 1

    @property
    def published_seq(self) -> int | None:
        """A fused vehicle's: the message seq planners have up to (as ``published_stamp_ns``:
        after a failover the last heard is sent again)."""
        if self.heard is None or self.heard.seq is None:
            return None
        return self.heard.seq if self.source == "handoff" else self.heard.seq - 1

    @property
    def needs_cache(self) -> bool:
        return self.missed > 0


@dataclass(frozen=True, slots=True)
class Heard:
    """The latest tracks frame heard on a sensor's key, from any member."""

    stamp_ns: int
    next_id: int  # above every id heard on the key
    seq: int | None = None  # a fused vehicle's message seq (its own counter)


@dataclass
class Shared:
    """What the workers' custodies share (thread-safe parts only)."""

    membership: Membership
    session: zenoh.Session
    keys: Keys
    metrics: Metrics
    instance: str
    digest: str
    handoff_timeout_s: float
    # vehicle/sensor -> the last tracks frame heard on its key (any member's)
    published: dict[str, Heard] = field(default_factory=dict)
    # vehicle/sensor -> a snapshot from this member's state dir, used when no member has it
    local: dict[str, SensorSnapshot] = field(default_factory=dict)
    lock: threading.Lock = field(default_factory=threading.Lock)
    counts: dict[str, int] = field(  # for the status reply; the metrics count the same
        default_factory=lambda: {"handoffs_in": 0, "handoffs_out": 0, "failovers": 0}
    )

    def count(self, what: str) -> None:
        with self.lock:
            self.counts[what] += 1


class Custody:
    def __init__(
        self, shared: Shared, registry: SensorRegistry, outbox: Outbox, standby_frames: int
    ) -> None:
        self.shared, self.registry, self.outbox = shared, registry, outbox
        self.standby = Standby(standby_frames)
        self.released: dict[str, Released] = {}
        self.settled: set[str] = set()  # sensors whose takeover was done (held or new)
        # Called with a stream's key before it is released (a fused vehicle's waiting
        # frames are applied first, so that its state is exact).
        self.before_release: Callable[[str], None] = lambda key: None
        self.fused_sensors: tuple[str, ...] = ()  # the sensors a vehicle's stream fuses

    # ------------------------------------------------------------------ routing
    def role(self, sensor: str) -> Role:
        role = self.shared.membership.role(sensor)
        if role is Role.OWNER:
            rel = self.released.get(sensor)
            if (
                rel is not None
                and rel.to not in self.shared.membership.members
                and time.monotonic() - rel.at < RELEASE_GUARD_S
            ):
                return Role.STANDBY  # keep its frames in case the asker never shows up
        return role

    def on_checkpoint(self, item: Inbound) -> None:
        snap = decode_message(item.payload, SensorSnapshot, _SNAP_LIMITS)
        if isinstance(snap, Rejection):
            log.warning("checkpoint_invalid", key=item.key, reason=snap.reason.value)
            return
        sensor = f"{snap.vehicle}/{snap.sensor}"
        if self.registry.get(sensor) is None:
            self.standby.checkpoint(sensor, snap)

    # ------------------------------------------------------------------ taking over
    def take_over(
        self,
        vehicle: str,
        sensor: str,
        replies: list[SensorSnapshot],
        waiting: Sequence[Inbound] = (),
    ) -> Takeover:
        """This member owns the sensor and does not hold it: its latest state is the
        holder's answer (``replies``, from ``ask``), else the standby checkpoint, else this
        member's state directory; then the frames kept since. ``waiting``: the frames that
        came while the group was asked. ``complete`` finishes it (after ``fetch_cache``
        when the frames leave a gap after the state)."""
        key = f"{vehicle}/{sensor}"
        self.settled.add(key)
        self.released.pop(key, None)
        checkpoint, frames = self.standby.take(key)
        if sensor == VEHICLE_STREAM:
            # Kept as the sensors' own streams before fusion was on in the group (a rolling
            # upgrade's last old member just left): those no member answered on the
            # sensor's own key are the vehicle's now.
            for name in self.fused_sensors:
                with self.shared.lock:
                    answered = self.shared.published.get(f"{vehicle}/{name}")
                kept = self.standby.take(f"{vehicle}/{name}")[1]
                upto = None if answered is None else answered.stamp_ns
                frames += [f for f in kept if _after(f, upto)]
        snap, source = None, "new"
        if replies:
            snap, source = max(replies, key=lambda s: s.written_ns), "handoff"
        else:
            local = self.shared.local.pop(key, None)
            candidates = [(c, "failover") for c in (checkpoint,) if c is not None]
            candidates += [(c, "restore") for c in (local,) if c is not None]
            if candidates:
                snap, source = max(candidates, key=lambda c: c[0].written_ns)
        with self.shared.lock:
            heard = self.shared.published.get(key)
        if source == "new" and heard is not None:
            # Another member published this sensor's tracks and nobody has its state (it
            # died before its first checkpoint, or with its standby): tracks start afresh,
            # their ids above every one heard.
            source = "lost"
            self.registry.retired[key] = max(self.registry.retired.get(key, 0), heard.next_id)
        t = Takeover(vehicle, sensor, source, snap, heard)
        adopted = None if snap is None else self.registry.adopt(snap, use_floor=source == "restore")
        if isinstance(adopted, VehicleState):
            t.vehicle_state = adopted
            t.replay = [f for f in frames if not adopted.covers(f)]
            if source in ("failover", "handoff"):
                t.missed = adopted.holes([*t.replay, *waiting])
            return t
        t.state = adopted
        t.replay = [f for f in frames if _after(f, t.covered_stamp_ns)]
        if source in ("failover", "handoff") and snap is not None:
            t.missed = _holes(snap.last_seq, [*t.replay, *waiting])
        return t

    def complete(self, t: Takeover, cached: list[Inbound], waiting: Sequence[Inbound] = ()) -> None:
        """Add the frames the vehicle's cache gave (those after the state the standby did
        not keep), count what is still missing, and account for the takeover."""
        vs = t.vehicle_state
        if cached:
            have = {(f.key, stamp_of(f)) for f in [*t.replay, *waiting]}
            extra = [
                f
                for f in cached
                if (not vs.covers(f) if vs is not None else _after(f, t.covered_stamp_ns))
                and (f.key, stamp_of(f)) not in have
            ]
            t.from_cache = len(extra)
            t.replay += extra  # put in order with the waiting frames by the worker
            if vs is not None:
                t.missed = vs.holes([*t.replay, *waiting])
            elif t.snapshot is not None:
                t.missed = _holes(t.snapshot.last_seq, [*t.replay, *waiting])
        m = self.shared.metrics
        if t.source == "handoff":
            m.handoffs.labels(direction="in").inc()
            self.shared.count("handoffs_in")
        elif t.source in ("failover", "lost"):
            m.failovers.inc()
            self.shared.count("failovers")
        held = t.state if t.state is not None else t.vehicle_state
        if t.missed and held is not None:
            # Tracks may have been born in the frames lost: new ids start past any of them.
            floor = 0 if t.heard is None else t.heard.next_id - held.id_base
            held.tracker.next_id = max(held.tracker.next_id + ID_BLOCK, floor)
        log.info(
            "sensor_taken_over",
            vehicle=t.vehicle,
            sensor=t.sensor,
            source=t.source,
            seq=None if t.snapshot is None else t.snapshot.last_seq,
            replay=len(t.replay),
            from_vehicle_cache=t.from_cache,
            missed=t.missed,
            members=len(self.shared.membership.members),
        )

    def fetch_cache(
        self, vehicle: str, sensor: str, on_done: Callable[[list[Inbound]], None]
    ) -> None:
        """The frames the vehicle's advanced publisher still caches (its last
        ``cache_frames``), from its cache queryable under ``<detections key>/@adv``.
        ``on_done`` runs on a Zenoh thread."""
        sh = self.shared
        got: list[Inbound] = []

        def on_reply(reply: zenoh.Reply) -> None:
            if reply.ok is not None:
                sample = reply.ok
                got.append(
                    Inbound(
                        str(sample.key_expr),
                        sample.payload.to_bytes(),
                        time.time_ns(),
                        time.perf_counter(),
                    )
                )

        # A fused vehicle's frames are its sensors': every one's cache answers.
        key = sh.keys.detections(vehicle, "*" if sensor == VEHICLE_STREAM else sensor)
        try:
            sh.session.get(
                f"{key}/@adv/**",
                zenoh.handlers.Callback(on_reply, lambda: on_done(got)),
                target=zenoh.QueryTarget.ALL,
                consolidation=zenoh.ConsolidationMode.NONE,
                accept_replies=zenoh.ReplyKeyExpr.ANY,  # the cache answers on the frames' key
                timeout=sh.handoff_timeout_s,
            )
        except zenoh.ZError as e:
            log.warning("vehicle_cache_failed", vehicle=vehicle, sensor=sensor, error=str(e))
            on_done([])

    def needs_asking(self) -> bool:
        """False when no other member could hold a sensor (alone, nothing released)."""
        return len(self.shared.membership.members) > 1 or bool(self.released)

    def ask(
        self,
        vehicle: str,
        sensor: str,
        on_done: Callable[[list[SensorSnapshot]], None],
    ) -> None:
        """Ask every other member to release the sensor; the holder answers its state.
        ``on_done(states)`` runs on a Zenoh thread once every member answered (or
        ``handoff_timeout_s``)."""
        sh = self.shared
        found: list[SensorSnapshot] = []

        def on_reply(reply: zenoh.Reply) -> None:
            if reply.ok is None:  # members answer nothing or a state, never an error
                log.warning("handoff_error_reply", vehicle=vehicle, sensor=sensor)
                return
            snap = decode_message(reply.ok.payload.to_bytes(), SensorSnapshot, _SNAP_LIMITS)
            if isinstance(snap, Rejection):
                log.warning("handoff_invalid", vehicle=vehicle, sensor=sensor)
            elif (snap.vehicle, snap.sensor) == (vehicle, sensor):
                found.append(snap)

        try:
            sh.session.get(
                zenoh.Selector(sh.keys.handoff("*", vehicle, sensor), f"from={sh.instance}"),
                zenoh.handlers.Callback(on_reply, lambda: on_done(found)),
                target=zenoh.QueryTarget.ALL,
                consolidation=zenoh.ConsolidationMode.NONE,
                timeout=sh.handoff_timeout_s,
            )
        except zenoh.ZError as e:
            log.warning("handoff_ask_failed", vehicle=vehicle, sensor=sensor, error=str(e))
            on_done([])

    # ------------------------------------------------------------------ giving away
    def release(self, vehicle: str, sensor: str, to: str) -> SensorSnapshot | None:
        """Give the sensor up to ``to`` (a member that owns it in its view): its exact
        state, and this member tracks it no more. Asked again, the same state."""
        key = f"{vehicle}/{sensor}"
        state = self.registry.get(key)
        if state is None:
            rel = self.released.get(key)
            return None if rel is None else rel.snapshot
        self.before_release(key)
        snap = state.snapshot(self.registry.digest)
        # Released first, then gone: a question read without the lock (app.py) must never
        # see the sensor neither held nor released.
        self.released[key] = Released(snap, to, time.monotonic())
        self.registry.release(key)
        self.outbox.forget(vehicle, sensor)
        self.settled.discard(key)
        self.shared.metrics.handoffs.labels(direction="out").inc()
        self.shared.count("handoffs_out")
        log.info("sensor_handed_off", vehicle=vehicle, sensor=sensor, to=to, seq=snap.last_seq)
        return snap

    def release_unowned(self) -> None:
        """Sensors held here that another member now owns go when it asks; those it never
        asks for (silent) are let go here, so a later frame finds them with that member."""
        for key in list(self.registry.sensors):
            if self.role(key) is not Role.OWNER:
                vehicle, sensor = key.split("/")
                owner = self.shared.membership.owner(key)
                self.release(vehicle, sensor, owner)

    # ------------------------------------------------------------------ checkpoints
    def send_checkpoints(self, final: bool = False, new_standby_only: bool = False) -> int:
        """Each held sensor changed since its last checkpoint goes to its standby;
        ``new_standby_only``: only those whose standby has none yet (a new sensor, a new
        standby); ``final``: every held sensor, at shutdown."""
        sh = self.shared
        sent = 0
        for key, s in list(self.registry.sensors.items()):
            standby = sh.membership.standby(key)
            if standby is None:
                continue
            mark = (standby, s.frames)
            last = s.checkpoint_mark
            first = last is None or last[0] != standby  # this standby has no state of it
            if not (final or first or (last != mark and not new_standby_only)):
                continue
            snap = s.snapshot(self.registry.digest)
            try:
                sh.session.put(
                    sh.keys.checkpoint(standby, s.vehicle, s.sensor),
                    encode(snap),
                    encoding=MSGPACK,
                    congestion_control=zenoh.CongestionControl.BLOCK,
                )
            except zenoh.ZError as e:
                log.warning("checkpoint_failed", vehicle=s.vehicle, sensor=s.sensor, error=str(e))
                continue
            s.checkpoint_mark = mark
            sent += 1
        if sent:
            sh.metrics.checkpoints_sent.inc(sent)
        return sent

    def housekeeping(self) -> None:
        now = time.monotonic()
        for key in [k for k, r in self.released.items() if now - r.at > RELEASED_KEPT_S]:
            del self.released[key]
        for key in self.standby.sensors():
            if self.shared.membership.role(key) is Role.NONE:
                self.standby.forget(key)


def _after(item: Inbound, stamp_ns: int | None) -> bool:
    if stamp_ns is None:
        return True
    stamp = stamp_of(item)
    return stamp is None or stamp > stamp_ns


def _holes(last_seq: int | None, replay: list[Inbound], limit: int = 100_000) -> int:
    """Seqs between the state's last and the last frame to replay that none of them has."""
    if last_seq is None or not replay:
        return 0
    seqs = {s for s in (peek_header(f.payload)[0] for f in replay) if s is not None}
    top = max(seqs, default=last_seq)
    if top - last_seq > limit:  # a restarted publisher's seq: not a gap to count
        return 0
    return sum(1 for q in range(last_seq + 1, top + 1) if q not in seqs)
