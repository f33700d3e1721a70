"""A worker's side of the group protocol (docs/SCALE.md): the Zenoh and registry half of
custody. What to do with each frame, which state to take over and what to replay is decided
by the pure machine (server/custody_machine.py); this carries out what it cannot: asking the
group and the vehicles' caches, adopting and releasing states, checkpoints to the standbys.

Only the worker's thread calls it, except ``release`` after the workers have stopped.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import TypeAlias

import zenoh

from simpletrack.server.checkpoint_rule import CheckpointMark, checkpoint_due
from simpletrack.server.custody_machine import (
    Action,
    Budget,
    CustodyMachine,
    FetchCache,
    Heard,
    Limits,
    Released,
    Role,
    SensorCoverage,
    Source,
    Takeover,
    View,
)
from simpletrack.server.group import Membership
from simpletrack.server.heard import HeardStreams
from simpletrack.server.intake import FINAL_CHECKPOINT, FRAME_OVERHEAD, Inbound
from simpletrack.server.logs import get_logger
from simpletrack.server.metrics import Metrics
from simpletrack.server.outbox import MSGPACK, Outbox
from simpletrack.server.registry import SensorRegistry
from simpletrack.server.sensors import SensorState
from simpletrack.server.snapshots import ID_BLOCK
from simpletrack.server.vehicles import VehicleState
from simpletrack.wire.codec import DecodeLimits, Rejection, decode_message, encode
from simpletrack.wire.header import peek_header
from simpletrack.wire.keys import VEHICLE_STREAM, Keys
from simpletrack.wire.models import SensorSnapshot

log = get_logger("group")
_SNAP_LIMITS = DecodeLimits(max_bytes=1 << 30, max_boxes=1 << 30)


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
    checkpoint_frames: int  # the checkpoint rule's (server/checkpoint_rule.py)
    checkpoint_max_age_s: float
    # vehicle/sensor -> the last tracks frame heard on its key (any other member's)
    heard: HeardStreams
    lock: threading.Lock = field(default_factory=threading.Lock)
    counts: dict[str, int] = field(  # for the status reply; the metrics count the same
        default_factory=lambda: {"handoffs_in": 0, "handoffs_out": 0, "failovers": 0}
    )
    # A stream's sensors first published while this member runs, claimed by its takeover
    # (server/sensor_tokens.py; none without per-sensor subscriptions).
    fresh: Callable[[str], frozenset[str]] = lambda stream: frozenset()

    def count(self, what: str) -> None:
        with self.lock:
            self.counts[what] += 1


Actions: TypeAlias = list[Action[Inbound]]


def peek(item: Inbound) -> tuple[str, int | None, int | None]:
    """What the machine reads of a frame: its key, seq and stamp (the header alone)."""
    seq, stamp = peek_header(item.payload)
    return item.key, seq, stamp


class Custody:
    def __init__(
        self,
        shared: Shared,
        registry: SensorRegistry,
        outbox: Outbox,
        limits: Limits,
        budget: Budget | None = None,
    ) -> None:
        self.shared, self.registry, self.outbox = shared, registry, outbox
        self.machine: CustodyMachine[Inbound] = CustodyMachine(
            peek, limits, budget, lambda item: len(item.payload) + FRAME_OVERHEAD
        )
        # Called with a stream's key before it is released (a fused vehicle's waiting
        # frames are applied first, so that its state is exact).
        self.before_release: Callable[[str], None] = lambda key: None
        self._taking: dict[str, Takeover[Inbound]] = {}

    @property
    def released(self) -> dict[str, Released]:
        """Streams this member gave away lately (their answer, if asked again)."""
        return self.machine.released

    def view(self, stream: str) -> View:
        """The group as seen for ``stream``; its owner is ranked only when it is another
        member (every frame comes here: the owner's own frames pay no hashing)."""
        m = self.shared.membership
        role = m.role(stream)
        return View(m.me, m.members, role, m.me if role is Role.OWNER else m.owner(stream))

    def group_view(self) -> View:
        """The members alone (the worker's beat asks nothing of any stream)."""
        m = self.shared.membership
        return View(m.me, m.members, Role.OWNER, m.me)

    def heard(self, stream: str) -> Heard | None:
        return self.shared.heard.get(stream)

    def role(self, stream: str) -> Role:
        return self.machine.role(stream, self.view(stream), time.monotonic())

    def on_checkpoint(self, item: Inbound) -> Actions:
        """A state sent to this member: a checkpoint of a stream it stands by for; or, for a
        stream it holds, a state with a higher epoch, pushed by a member that took the stream
        over while the two could not see each other (a healed partition): this member's
        state is stale, and it is fenced (it asks for the stream, and gets that state)."""
        snap = decode_message(item.payload, SensorSnapshot, _SNAP_LIMITS)
        if isinstance(snap, Rejection):
            log.warning("checkpoint_invalid", key=item.key, reason=snap.reason.value)
            return []
        stream = f"{snap.vehicle}/{snap.sensor}"
        held = self.registry.get(stream)
        if held is None:
            self.machine.checkpoint(stream, snap, item.final)
            if item.tracks is not None:
                self.shared.heard.add(stream, item.tracks, snap.sensor == VEHICLE_STREAM)
            return []
        if snap.epoch is not None and snap.epoch > held.epoch:
            acts = self.machine.superseded(stream, time.monotonic())
            if acts:
                self.shared.metrics.fences.labels(why="superseded").inc()
            return acts
        return []

    # ------------------------------------------------------------------ taking over
    def promoted(self, current: Callable[[str], bool]) -> Actions:
        """The group changed: streams this member stood by for and owns now, with frames the
        old owner never answered, are asked for at once (``current``: the stream's frames
        go to it now)."""
        return self.machine.promoted(self.view, self.heard, time.monotonic(), current)

    def answered(self, stream: str, replies: Sequence[SensorSnapshot]) -> Actions:
        """The group answered: the machine picks the state, the registry adopts it (its ids
        exact: the floors apply only if the replay leaves a hole), the machine says what
        to replay (or to ask the vehicle's cache first)."""
        t = self.machine.answered(stream, replies, self.heard)
        if t.source is Source.LOST and t.heard is not None:
            retired = self.registry.retired
            retired[stream] = max(retired.get(stream, 0), t.heard.next_id)
        adopted = None if t.snapshot is None else self.registry.adopt(t.snapshot, use_floor=False)
        if t.source is Source.RESTORE and adopted is not None:
            self.shared.metrics.restored.inc()
        # A state taken here, even a fresh one, has a higher epoch than any before it.
        epoch = t.epoch(self.shared.instance)
        if adopted is None:
            self.registry.epochs[stream] = epoch  # for the state its first frame creates
        else:
            adopted.epoch = epoch
        coverage: VehicleState | SensorCoverage[Inbound] | None = None
        if isinstance(adopted, VehicleState):
            coverage = adopted
            adopted.published_seq = t.published_seq  # messages planners have are not sent
        elif isinstance(adopted, SensorState) and t.snapshot is not None:
            coverage = SensorCoverage(t.snapshot.last_seq, t.snapshot.last_stamp_ns, peek)
        self._taking[stream] = t
        fresh = self.shared.fresh(stream)
        return self._done(stream, self.machine.adopted(stream, coverage, fresh))

    def cached(self, stream: str, frames: Sequence[Inbound], asked: int | None = None) -> Actions:
        return self._done(stream, self.machine.cached(stream, frames, asked))

    def _done(self, stream: str, acts: Actions) -> Actions:
        """A takeover complete (no cache to wait for): accounted and logged."""
        if any(isinstance(a, FetchCache) for a in acts):
            return acts
        t = self._taking.pop(stream, None)
        if t is None:
            return acts
        m = self.shared.metrics
        if t.source is Source.HANDOFF:
            m.handoffs.labels(direction="in").inc()
            self.shared.count("handoffs_in")
        elif t.source in (Source.FAILOVER, Source.LOST):
            m.failovers.inc()
            self.shared.count("failovers")
        if t.replay:
            m.replayed.inc(len(t.replay))
        vehicle, sensor = stream.split("/")
        log.info(
            "sensor_taken_over",
            vehicle=vehicle,
            sensor=sensor,
            source=t.source.value,
            seq=None if t.snapshot is None else t.snapshot.last_seq,
            replay=len(t.replay),
            from_vehicle_cache=t.from_cache,
            missed=t.missed,
            exact_ids=t.exact_ids,
            epoch=t.epoch(self.shared.instance),
            members=len(self.shared.membership.members),
        )
        return acts

    def raise_ids(self, stream: str, floor: int) -> None:
        """Tracks may have been born in frames nobody has: new ids start past any of them,
        above every id heard and this member's reservation on disk."""
        held = self.registry.get(stream)
        if held is None:
            return
        disk = max(self.registry.retired.get(stream, 0), self.registry.id_floor.get(stream, 0))
        lowest = max(floor, disk) - held.id_base
        held.tracker.next_id = max(held.tracker.next_id + ID_BLOCK, lowest)

    def fetch_cache(
        self,
        vehicle: str,
        sensor: str,
        on_done: Callable[[list[Inbound]], None],
        newest: int | None = None,
    ) -> None:
        """The frames the vehicle's advanced publisher still caches (its last
        ``cache_frames``; ``newest``: its newest that many, the cache's ``_max``), from its
        cache queryable under ``<detections key>/@adv``. ``on_done`` runs on a Zenoh
        thread."""
        sh = self.shared
        got: list[Inbound] = []

        def on_reply(reply: zenoh.Reply) -> None:
            if reply.ok is not None:
                sample = reply.ok
                info = sample.source_info
                got.append(
                    Inbound(
                        str(sample.key_expr),
                        sample.payload.to_bytes(),
                        time.time_ns(),
                        time.perf_counter(),
                        source_sn=None if info is None else info.source_sn,
                    )
                )

        # A fused vehicle's frames are its sensors': every one's cache answers.
        key = sh.keys.detections(vehicle, "*" if sensor == VEHICLE_STREAM else sensor)
        try:
            sh.session.get(
                f"{key}/@adv/**" + ("" if newest is None else f"?_max={newest}"),
                zenoh.handlers.Callback(on_reply, lambda: on_done(got)),
                target=zenoh.QueryTarget.ALL,
                consolidation=zenoh.ConsolidationMode.NONE,
                accept_replies=zenoh.ReplyKeyExpr.ANY,  # the cache answers on the frames' key
                timeout=sh.handoff_timeout_s,
            )
        except zenoh.ZError as e:
            log.warning("vehicle_cache_failed", vehicle=vehicle, sensor=sensor, error=str(e))
            on_done([])

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
    def release(
        self, vehicle: str, sensor: str, to: str, push: bool = False
    ) -> SensorSnapshot | None:
        """Give the stream up to ``to`` (a member that owns it in its view): its exact
        state, and this member tracks it no more. Asked again, the same state. ``push``
        (released unasked: ``to`` may hold an older state of it, from before a partition
        healed): the state also goes to ``to`` as a checkpoint, whose higher epoch fences
        that older state."""
        key = f"{vehicle}/{sensor}"
        state = self.registry.get(key)
        if state is None:
            rel = self.machine.released.get(key)
            return None if rel is None else rel.snapshot
        self.machine.release_asked(key, to, held=True)
        self.before_release(key)
        snap = self.registry.state_of(state)
        # Released first, then gone: a question read without the lock (app.py) must never
        # see the sensor neither held nor released.
        self.machine.released_as(key, snap, to, time.monotonic())
        self.registry.release(key)
        self.outbox.forget(vehicle, sensor)
        self.shared.metrics.handoffs.labels(direction="out").inc()
        self.shared.count("handoffs_out")
        log.info("sensor_handed_off", vehicle=vehicle, sensor=sensor, to=to, seq=snap.last_seq)
        if push:
            self._put_checkpoint(to, vehicle, sensor, snap, final=True)  # all published
        return snap

    def stash(self, stream: str) -> SensorSnapshot | None:
        """A fence: the stream's state leaves the registry without a message or a checkpoint
        and becomes this member's own candidate for the takeover that follows."""
        state = self.registry.get(stream)
        if state is None:
            return None
        snap = self.registry.state_of(state)
        vehicle, sensor = stream.split("/")
        self.machine.stashed(stream, snap, self.outbox.last.get((vehicle, sensor)))
        self.registry.release(stream)
        self.outbox.forget(vehicle, sensor)
        log.warning("sensor_fenced", vehicle=vehicle, sensor=sensor, seq=snap.last_seq)
        return snap

    def release_unowned(self) -> None:
        """Streams held here that another member now owns go when it asks; those it never
        asks for (silent) are let go here, so a later frame finds them with that member."""
        for key in list(self.registry.sensors):
            if self.role(key) is not Role.OWNER:
                vehicle, sensor = key.split("/")
                owner = self.shared.membership.owner(key)
                self.release(vehicle, sensor, owner, push=True)

    # ------------------------------------------------------------------ checkpoints
    def send_checkpoints(self, final: bool = False, new_standby_only: bool = False) -> int:
        """Each held sensor due a checkpoint goes to its standby (server/checkpoint_rule.py);
        ``new_standby_only``: only those whose standby has none yet (a new sensor, a new
        standby); ``final``: every held sensor, at shutdown."""
        sh = self.shared
        now = time.monotonic()
        sent = 0
        for key, s in list(self.registry.sensors.items()):
            standby = sh.membership.standby(key)
            if standby is None:
                continue
            if not checkpoint_due(
                s.checkpoint_mark,
                standby,
                s.frames,
                now,
                sh.checkpoint_frames,
                sh.checkpoint_max_age_s,
                final=final,
                new_standby_only=new_standby_only,
            ):
                continue
            snap = self.registry.state_of(s)
            if not self._put_checkpoint(standby, s.vehicle, s.sensor, snap, final):
                continue
            s.checkpoint_mark = CheckpointMark(standby, s.frames, now)
            sent += 1
        if sent:
            sh.metrics.checkpoints_sent.inc(sent)
        return sent

    def _put_checkpoint(
        self, to: str, vehicle: str, sensor: str, snap: SensorSnapshot, final: bool = False
    ) -> bool:
        sh = self.shared
        payload = encode(snap)
        try:
            sh.session.put(
                sh.keys.checkpoint(to, vehicle, sensor),
                payload,
                encoding=MSGPACK,
                congestion_control=zenoh.CongestionControl.BLOCK,
                attachment=self._attachment(vehicle, sensor, final),
            )
        except zenoh.ZError as e:
            log.warning("checkpoint_failed", vehicle=vehicle, sensor=sensor, error=str(e))
            return False
        sh.metrics.checkpoint_bytes.inc(len(payload))
        return True

    def _attachment(self, vehicle: str, sensor: str, final: bool) -> bytes | None:
        """A final checkpoint says so; another carries the stream's newest tracks message,
        which its standby does not hear (server/told.py): a failover whose state holds its
        frame publishes it again."""
        if final:
            return FINAL_CHECKPOINT
        return self.outbox.last.get((vehicle, sensor))

    def housekeeping(self) -> None:
        self.machine.housekeeping(time.monotonic(), self.shared.membership.role)
