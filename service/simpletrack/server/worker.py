"""Tracker workers: each owns a queue and the sensors hashed to it, and runs, per frame,
decode → ordering check → tracker step → publish. One thread per worker keeps a sensor's
frames strictly in order; sensors on different workers never wait for each other.
"""

from __future__ import annotations

import logging
import re
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field, replace

import zenoh

from simpletrack.core.config import TrackerConfig
from simpletrack.core.fusion_config import FusionConfig
from simpletrack.core.tracker import Tracker
from simpletrack.server.announcer import Announcer
from simpletrack.server.custody import Custody, Shared, peek
from simpletrack.server.custody_machine import (
    Action,
    AnnounceMissed,
    Ask,
    Coverage,
    Drop,
    FetchCache,
    Keep,
    Limits,
    NotOwned,
    RaiseIds,
    Release,
    Republish,
    Resend,
    Resolve,
    RestartCoverage,
    SensorCoverage,
    Skip,
    Stash,
    Track,
)
from simpletrack.server.finite import FloatingPointErrors, non_finite_refusal
from simpletrack.server.fused import FusedFrames
from simpletrack.server.gil import Trackers
from simpletrack.server.intake import BurstBudget, Dropped, Inbound, Kind, WorkQueue
from simpletrack.server.logs import get_logger
from simpletrack.server.metrics import Metrics
from simpletrack.server.outbox import Outbox, congestion_control, dropped, missed_notice
from simpletrack.server.plausibility import (
    Cause,
    Finding,
    LeastLag,
    StartThresholds,
    check_frame,
)
from simpletrack.server.registry import SensorRegistry
from simpletrack.server.sensors import (
    Arrival,
    Order,
    OrderRules,
    SensorBudget,
    SensorState,
    Verdict,
    check_order,
    key_mismatch,
    lead_ns,
    unheard_start,
)
from simpletrack.server.settings import ServiceSettings
from simpletrack.server.snapshots import SnapshotWriter
from simpletrack.server.streams import Streams, is_vehicle_stream
from simpletrack.server.vehicles import (
    VehicleState,
    fusion_digest,
    new_vehicle,
    vehicle_from_snapshot,
)
from simpletrack.wire.codec import (
    DecodedDetections,
    DecodeLimits,
    Rejection,
    decode_detection_frame,
    encode_track_frame,
)
from simpletrack.wire.columns import TrackArrays
from simpletrack.wire.convert import (
    detection_extents,
    frame_from_wire,
    pack_tracks_checked,
    tracks_to_wire,
)
from simpletrack.wire.header import peek_header, restamp_tracks
from simpletrack.wire.keys import Keys
from simpletrack.wire.models import NAME_PATTERN, SensorSnapshot
from simpletrack.wire.reasons import TRACK_EPOCH_SCHEMA_VERSION, ErrorReason

log = get_logger("pool")  # the logger of these lines since before the split (docs/SERVICE.md)
_MISSED_DETAIL = {
    "takeover": "{n} frames of the takeover's gap were kept neither by the standby nor by the "
    "vehicle's cache; ids continue past any born in them",
    "restart": "{n} frames a restarted publisher sent before any member heard it were no "
    "longer in the vehicle's cache",
}
NAME_RE = re.compile(NAME_PATTERN)
HOUSEKEEPING_S = 0.5
_WARNED_CAP = 10_000  # sensors whose logged causes are remembered (see Worker._warned)
_CLOCKS_CAP = 16_384  # sensors whose clock is estimated (past it the longest known is dropped)
_KEYS_CAP = 16_384  # frame keys whose names are remembered (see Worker._names)
_UNSEEN = ("", "")  # not yet in Worker._key_names (its values are names or None)


@dataclass
class Context:
    """What every worker shares (read-only after start, except the thread-safe parts)."""

    settings: ServiceSettings
    session: zenoh.Session
    keys: Keys
    metrics: Metrics
    tracker_config_digest: str
    new_tracker: Callable[[], Tracker]
    class_codes: dict[str, int]  # name -> tracker code; -1 for ignore_classes
    classes: tuple[str, ...]  # the tracks' class table
    budget: SensorBudget
    writer: SnapshotWriter | None
    shared: Shared
    announcer: Announcer  # publishes the workers' refusal notices (server/announcer.py)
    trackers: Trackers  # which workers track a frame now (server/gil.py)
    limits: DecodeLimits = field(default_factory=DecodeLimits)
    start_thresholds: StartThresholds | None = None  # None: no check of scores against them
    streams: Streams | None = None  # None: no sensor is fused
    tracker_config: TrackerConfig | None = None
    fusion: FusionConfig | None = None
    per_sensor_output: bool = False  # fused sensors also tracked on their own keys
    vehicle_frame_id: str = "base_link"
    burst: BurstBudget | None = None  # the member's bytes for bursts past the queues' bounds

    @property
    def vehicle_digest(self) -> str:
        if self.fusion is None:
            return ""
        return fusion_digest(self.tracker_config_digest, self.fusion)

    def stream(self, vehicle: str, sensor: str) -> str:
        """The stream key (server/streams.py) of a sensor's frames now."""
        if self.streams is None:
            return f"{vehicle}/{sensor}"
        return self.streams.stream(vehicle, sensor)

    @property
    def congestion(self) -> zenoh.CongestionControl:
        return congestion_control(self.settings.congestion_control)


class Worker(threading.Thread):
    def __init__(self, index: int, queue: WorkQueue, ctx: Context) -> None:
        super().__init__(name=f"tracker-{index}", daemon=True)
        self.index, self.queue, self.ctx = index, queue, ctx
        s = ctx.settings
        self.sensors = SensorRegistry(
            budget=ctx.budget,
            metrics=ctx.metrics,
            new_tracker=ctx.new_tracker,
            digest=ctx.tracker_config_digest,
            writer=ctx.writer,
            state_dir=s.state_dir,
            reclaim_after_s=s.reset_gap_s,
            new_vehicle=self._new_vehicle if ctx.fusion is not None else None,
            vehicle_of=self._vehicle_of if ctx.fusion is not None else None,
            vehicle_digest=ctx.vehicle_digest,
            state_format=s.state_format,
        )
        self.fused = FusedFrames(self)
        self.outbox = Outbox(
            ctx.session,
            ctx.keys,
            ctx.congestion,
            s.instance,
            ctx.announcer,
            ctx.shared.membership.standby,
        )
        self.rules = OrderRules(reset_gap_s=s.reset_gap_s, reset_backward_s=s.reset_backward_s)
        limits = Limits(s.standby_frames, s.fence_after_s, s.fence_hold_s)
        self.custody = Custody(ctx.shared, self.sensors, self.outbox, limits, ctx.burst)
        self.custody.before_release = self._before_release
        self.custody.machine.fused_sensors = () if ctx.fusion is None else ctx.fusion.names
        self.drain_deadline: float | None = None
        self.stopped = threading.Event()
        # Held while an item is handled: a member asking for a sensor takes it to release
        # the sensor from its own thread. Never held while waiting on another member.
        self.lock = threading.Lock()
        self._quiet = False  # tracking a frame planners have tracks of: publish nothing
        # The frame the custody machine answered as it came (not one of a replay, whose
        # later frames are on their way to the tracker already): only it may start a refill.
        self.live: Inbound | None = None
        self._superseding: set[str] = set()  # streams whose fence is queued
        # Since when this member reaches the group (the app sets it from the router watch;
        # None: a client without its router). A fenced stream waits for it.
        self.connected_at: float | None = time.monotonic()
        # vehicle/sensor -> causes already logged for it (once per sensor and cause while
        # the sensor is held; forgotten at eviction, cleared whole past _WARNED_CAP).
        self._warned: dict[str, set[Cause]] = {}
        # vehicle/sensor -> its clock against the service's (plausibility.LeastLag), from
        # its frames as they arrive; forgotten 20 s after its last frame. Read at scrapes.
        self._clocks: dict[str, LeastLag] = {}
        # frame key -> its (vehicle, sensor) when both are valid names, else None
        self._key_names: dict[str, tuple[str, str] | None] = {}
        ctx.metrics.watch_clocks(self.clock_lags)
        self._next_snapshot = time.monotonic() + s.snapshot_interval_s
        self._next_checkpoint = time.monotonic() + s.checkpoint_interval_s
        self._next_housekeeping = time.monotonic() + HOUSEKEEPING_S

    def _new_vehicle(self, vehicle: str, id_floor: int) -> VehicleState:
        ctx = self.ctx
        assert ctx.fusion is not None and ctx.tracker_config is not None
        f = ctx.fusion
        return new_vehicle(
            vehicle, ctx.tracker_config, f, ctx.vehicle_digest, f.window_s, f.silent_after_s,
            id_floor,
        )  # fmt: skip

    def _vehicle_of(self, snap: SensorSnapshot) -> VehicleState:
        ctx = self.ctx
        assert ctx.fusion is not None and ctx.tracker_config is not None
        return vehicle_from_snapshot(
            snap, ctx.tracker_config, ctx.fusion, ctx.vehicle_digest, ctx.new_tracker
        )

    def _before_release(self, key: str) -> None:
        state = self.sensors.get(key)
        if isinstance(state, VehicleState):
            self.fused.release(state, flush=True)

    # ------------------------------------------------------------------ the loop
    def _wait_s(self, due: float | None) -> float:
        """How long the loop may wait for an item: until ``due`` (a fused vehicle's next
        frame, the standbys' words), or housekeeping."""
        if due is None:
            return HOUSEKEEPING_S
        return min(HOUSEKEEPING_S, max(0.0, due - time.monotonic()) + 0.001)

    def handle(self, item: Inbound | Dropped | Callable[[], None] | None) -> float | None:
        """One turn of the loop: the item taken from the queue (None: none came in time), then
        what is due. Returns when a fused vehicle's next frame is due (core/reorder.py), or
        the standbys' waiting words (server/told.py), whichever is first."""
        with self.lock:
            # Before the item: a process stopped past the lease finds itself fenced before it
            # tracks (or publishes) anything from its stale state.
            self._beat()
            if isinstance(item, Inbound):
                if item.kind is Kind.CHECKPOINT:
                    self._carry(self.custody.on_checkpoint(item))
                elif self.drain_deadline is not None and time.monotonic() > self.drain_deadline:
                    self._drop(item, ErrorReason.DROPPED_SHUTDOWN)
                else:
                    self._process(item)
            elif isinstance(item, Dropped):
                self._announce(item)
            elif item is not None:
                item()
            due = self.fused.release_due()
            if time.monotonic() >= self._next_housekeeping:
                self._housekeeping()
            teller = self.outbox.teller
            if teller is None:
                return due
            # Standbys are told of the messages out FLUSH_S after the first of them
            # (server/told.py): one message for many, not one each, however they are spread.
            if teller.due():
                teller.flush()
            return min((t for t in (due, teller.deadline()) if t is not None), default=None)

    def run(self) -> None:
        due: float | None = None  # read under the lock, where the vehicles' buffers change
        while True:
            item = self.queue.get(timeout=self._wait_s(due))
            if item is None and self.queue.closed:
                break
            try:
                due = self.handle(item)
            except Exception:  # never let one frame kill the thread of many sensors
                log.error("worker_error", exc=True, worker=self.index)
        self._settle_pending()
        with self.lock:
            self.fused.flush_all()  # frames waiting in a vehicle's window: applied, published
        self.sensors.snapshot_dirty()
        # Every sensor's exact state to the member that takes it when this one leaves.
        self.custody.send_checkpoints(final=True)
        self.outbox.close()
        self.stopped.set()

    def _settle_pending(self) -> None:
        """At the end, takeovers still waiting for answers finish with what they have."""
        for act in self.custody.machine.settle():
            self._carry([act])

    def _beat(self) -> None:
        """The custody machine's clock: a stopped process finds itself fenced here, before
        any of its streams' frames is tracked again."""
        view = self.custody.group_view()
        acts = self.custody.machine.beat(time.monotonic(), view, self.connected_at)
        stashed = sum(isinstance(a, Stash) for a in acts)
        if stashed:
            self.ctx.metrics.fences.labels(why="stopped").inc(stashed)
        self._carry(acts)

    def _housekeeping(self) -> None:
        now = time.monotonic()
        self._next_housekeeping = now + HOUSEKEEPING_S
        gone = self.sensors.evict_idle(now, self.ctx.settings.sensor_idle_s)
        gone += self.sensors.reclaimed_now
        self.sensors.reclaimed_now = []
        for s in gone:
            self.outbox.forget(s.vehicle, s.sensor)
            self._warned.pop(f"{s.vehicle}/{s.sensor}", None)
            self.custody.machine.gone(f"{s.vehicle}/{s.sensor}")
        now_ns = time.time_ns()
        for key in [k for k, c in self._clocks.items() if not c.fresh(now_ns)]:
            del self._clocks[key]
        self.custody.housekeeping()
        self.outbox.flush_logs()
        # A standby without any state of a sensor gets it now, not at the next interval.
        self.custody.send_checkpoints(new_standby_only=True)
        if now >= self._next_checkpoint:
            self._next_checkpoint = now + self.ctx.settings.checkpoint_interval_s
            self.custody.release_unowned()
            self.custody.send_checkpoints()
        if now >= self._next_snapshot:
            # On a fixed grid from the worker's start: the workers' snapshots stay in step
            # instead of drifting apart by each one's lateness.
            interval = self.ctx.settings.snapshot_interval_s
            self._next_snapshot += interval
            if self._next_snapshot <= now:  # a worker stalled for a whole interval
                self._next_snapshot = now + interval
            self.sensors.snapshot_dirty()

    # ------------------------------------------------------------------ one frame
    def _process(self, item: Inbound) -> None:
        """Track the frames of the streams this member owns (taking a stream over first when
        it does not hold it yet); keep those it stands by for; ignore the others: as the
        custody machine says. A fused sensor's frames are its vehicle's stream's
        (server/streams.py)."""
        names = self._names(item.key)
        if names is not None:
            key = self.ctx.stream(*names)
            view = self.custody.view(key)
            self.live = item
            try:
                self._carry(self.custody.machine.frame(key, item, view, time.monotonic()))
            finally:
                self.live = None
            return
        self._track(item)

    def _names(self, key: str) -> tuple[str, str] | None:
        """(vehicle, sensor) of a frame's key when both are valid names, else None; each
        key's answer is remembered (a sensor's frames come on one key, frame after frame)."""
        names = self._key_names.get(key, _UNSEEN)
        if names is _UNSEEN:
            split = self.ctx.keys.sensor_of(key)
            valid = split is not None and all(NAME_RE.fullmatch(name) for name in split)
            names = split if valid else None
            if len(self._key_names) >= _KEYS_CAP:
                self._key_names.clear()  # keys come from the fleet: the memory stays bounded
            self._key_names[key] = names
        return names

    def _carry(self, acts: list[Action[Inbound]]) -> None:
        """Carry out the custody machine's actions, in order."""
        for act in acts:
            if isinstance(act, Track):
                self._track_in(act.stream, act.frame, act.publish, act.replayed)
            elif isinstance(act, Skip | Keep):
                continue
            elif isinstance(act, NotOwned):
                self.ctx.metrics.not_owned.inc()
            elif isinstance(act, Release):
                vehicle, holder = act.stream.split("/")
                if self.sensors.get(act.stream) is not None:
                    self.custody.release(vehicle, holder, act.to, push=True)
            elif isinstance(act, Ask):
                self._ask(act.stream)
            elif isinstance(act, Resolve):
                self._carry(self.custody.answered(act.stream, []))
            elif isinstance(act, FetchCache):
                self._fetch_cache(act.stream, act.newest)
            elif isinstance(act, Drop):
                self._drop(act.frame, act.reason)
            elif isinstance(act, AnnounceMissed):
                vehicle, holder = act.stream.split("/")
                if act.restarted is not None:
                    self._announce_missed(vehicle, act.restarted, act.frames, at="restart")
                else:
                    self._announce_missed(vehicle, holder, act.frames)
            elif isinstance(act, RaiseIds):
                self.custody.raise_ids(act.stream, act.floor)
            elif isinstance(act, Stash):
                self._stash(act.stream)
            elif isinstance(act, Resend):
                vehicle, holder = act.stream.split("/")
                self.outbox.resend(vehicle, holder, act.payload)
            elif isinstance(act, Republish):
                self._republish(act.stream, act.payload)

    def _track_in(self, stream: str, item: Inbound, publish: bool, replayed: bool) -> None:
        if is_vehicle_stream(stream):
            names = self.ctx.keys.sensor_of(item.key)
            if names is not None:
                self.fused.track(item, names[0], names[1], replayed=replayed)
            return
        if publish:
            self._track(item)
            return
        self._quiet = True
        try:
            self._track(item)
        finally:
            self._quiet = False

    def supersede(self, stream: str) -> None:
        """From a Zenoh thread: another member published ``stream`` with a higher epoch."""
        if stream in self._superseding:
            return  # one fence per stream is on its way already
        self._superseding.add(stream)

        def fence() -> None:
            self._superseding.discard(stream)
            acts = self.custody.machine.superseded(stream, time.monotonic())
            if acts:
                self.ctx.metrics.fences.labels(why="superseded").inc()
            self._carry(acts)

        self.queue.put_control(fence, force=True)

    def _stash(self, stream: str) -> None:
        """Fenced: a fused vehicle's frames waiting in its window go back to wait for the
        takeover (unapplied), then the state leaves the registry unpublished."""
        state = self.sensors.get(stream)
        if isinstance(state, VehicleState):
            self.custody.machine.requeue(stream, [w.item for w in state.buffer.flush()])
            self.fused.forget(stream)
        self.custody.stash(stream)

    def group_changed(self) -> None:
        """From the membership's thread: the streams this member now owns with frames their
        old owner never answered are taken over on this worker's thread, at its next turn."""
        self.queue.put_control(
            lambda: self._carry(self.custody.promoted(self._current)), force=True
        )

    def _current(self, stream: str) -> bool:
        """The stream is the one its sensors' frames go to now (fusion's gate decides
        between a sensor's own stream and its vehicle's)."""
        vehicle, name = stream.split("/")
        if not is_vehicle_stream(stream):
            return self.ctx.stream(vehicle, name) == stream
        sensors = () if self.ctx.streams is None else self.ctx.streams.sensors
        return any(self.ctx.stream(vehicle, s) == stream for s in sensors)

    def _ask(self, stream: str) -> None:
        """Ask the group for a stream without waiting: its frames wait in the machine and
        the answers come back through the queue's control lane."""
        vehicle, holder = stream.split("/")

        def done(answers: list[SensorSnapshot]) -> None:
            self.queue.put_control(
                lambda: self._carry(self.custody.answered(stream, answers)), force=True
            )

        self.custody.ask(vehicle, holder, done)

    def _fetch_cache(self, stream: str, newest: int | None) -> None:
        vehicle, holder = stream.split("/")

        def done(cached: list[Inbound]) -> None:
            self.queue.put_control(
                lambda: self._carry(self.custody.cached(stream, cached, newest)), force=True
            )

        self.custody.fetch_cache(vehicle, holder, done, newest)

    def _republish(self, stream: str, payload: bytes) -> None:
        """The newest message heard on the stream's key, as this member's (a failover whose
        checkpoint holds its frame: custody_machine.Republish)."""
        state = self.sensors.get(stream)
        vehicle, holder = stream.split("/")
        epoch = None if state is None else state.epoch
        again = restamp_tracks(payload, self.ctx.settings.instance, epoch, time.time_ns())
        if again is None:
            return
        log.info("tracks_republished", vehicle=vehicle, sensor=holder,
                 seq=peek_header(payload)[0])  # fmt: skip
        self.ctx.metrics.republished.inc()
        self.outbox.resend(vehicle, holder, again)

    def _announce_missed(self, vehicle: str, sensor: str, n: int, at: str = "takeover") -> None:
        """``at``: a takeover's gap (a fused vehicle's told per sensor) or a restarted
        publisher's frames before its first heard (``restart``, on its own sensor)."""
        state = self.sensors.get(f"{vehicle}/{sensor}")
        if at == "takeover" and isinstance(state, VehicleState):  # on each sensor's errors key
            for name, k in state.missed_by_sensor.items():
                if k:
                    self._announce_missed(vehicle, name, k)
            return
        self.ctx.metrics.count_missed(vehicle, n)
        log.warning("frames_missed", vehicle=vehicle, sensor=sensor, missed=n, at=at)
        detail = _MISSED_DETAIL[at].format(n=n)
        self.outbox.notice(missed_notice(vehicle, sensor, detail, self.ctx.settings.instance))

    def refill(
        self, stream: str, item: Inbound, last: Arrival, arrival: Arrival, held: Coverage[Inbound]
    ) -> bool:
        """``item`` is a restarted publisher's first frame heard here and not its first
        (sensors.unheard_start), come live: it waits while the vehicle's cache is asked for
        the frames before it (the custody machine's ``refill``). False: track it now (the
        stream is in a takeover, or this publisher session was asked for already).
        ``held``: what the stream's state covers."""
        session = arrival.session_id
        if session is None:
            return False
        cov = RestartCoverage(held, item.key, _source_sn, peek)
        acts = self.custody.machine.refill(stream, item, cov, session)
        if acts is None:
            return False
        vehicle, sensor = self._names(item.key) or ("", "")  # a key tracked already: valid
        self.ctx.metrics.restart_refills.inc()
        log.info("publisher_restart_unheard", vehicle=vehicle, sensor=sensor, seq=arrival.seq,
                 last_seq=last.seq, stream=stream)  # fmt: skip
        self._carry(acts)
        return True

    def _track(self, item: Inbound) -> None:
        ctx, m = self.ctx, self.ctx.metrics
        t0 = time.perf_counter()
        m.stages["queue"].observe(t0 - item.received_at)
        names = self._names(item.key)
        if names is None:
            # No errors key can be derived from a key like this: count and log only.
            m.count_error(ErrorReason.INVALID_VALUE, "")
            log.warning("frame_rejected", key=item.key, reason="invalid_value", field="key")
            return
        vehicle, sensor = names
        state = self.sensors.sensor(f"{vehicle}/{sensor}")

        decoded = decode_detection_frame(
            item.payload, ctx.limits, ctx.class_codes, detection_extents
        )
        t1 = time.perf_counter()
        m.stages["decode"].observe(t1 - t0)
        if isinstance(decoded, Rejection):
            self._refuse(item, vehicle, sensor, decoded)
            return
        frame = decoded.frame
        seq, stamp_ns = frame.seq, frame.stamp_ns
        mismatch = key_mismatch(frame, vehicle, sensor)
        if mismatch is not None:
            self._refuse(item, vehicle, sensor, mismatch)
            return
        # Before the ordering rules: a stamp in seconds explains the refusals that follow.
        flagged = not self._quiet and self._plausible(vehicle, sensor, seq, decoded, item)

        arrival = Arrival(seq, stamp_ns, item.received_ns, frame.session_id)
        last = None if state is None else state.last
        if (
            last is not None
            and item is self.live
            and unheard_start(last, arrival)
            and self.refill(
                f"{vehicle}/{sensor}",
                item,
                last,
                arrival,
                SensorCoverage(last.seq, last.stamp_ns, peek),
            )
        ):
            return
        fresh = state is None
        if state is None:
            added = self.sensors.add(vehicle, sensor, seq)
            if not isinstance(added, SensorState):
                detail = (
                    f"already tracking max_sensors={ctx.budget.limit} sensors, none of this "
                    f"worker's silent for over reset_gap_s"
                )
                r = Rejection(ErrorReason.TOO_MANY_SENSORS, None, detail, seq, stamp_ns)
                self._refuse(item, vehicle, sensor, r)
                return
            state = added
        with ctx.trackers.tracking(self.index):
            self._step_sensor(item, decoded, state, arrival, flagged, fresh, (t0, t1))

    def _per_sensor(
        self,
        vehicle_state: VehicleState,
        sensor: str,
        item: Inbound,
        decoded: DecodedDetections,
        arrival: Arrival,
    ) -> None:
        """A fused sensor's own tracks too (``fusion.per_sensor_output``): its tracker lives
        in its vehicle's stream and goes wherever the vehicle goes."""
        vehicle = vehicle_state.vehicle
        state = vehicle_state.per_sensor.get(sensor)
        fresh = state is None
        if state is None:
            floor = self.sensors.retired.pop(f"{vehicle}/{sensor}", 0)
            state = vehicle_state.per_sensor[sensor] = SensorState(
                vehicle, sensor, self.ctx.new_tracker(), id_base=floor
            )
        state.epoch = vehicle_state.epoch  # its messages are the vehicle stream's custody's
        now = time.perf_counter()
        with self.ctx.trackers.tracking(self.index):
            self._step_sensor(item, decoded, state, arrival, False, fresh, (now, now))

    def _step_sensor(
        self,
        item: Inbound,
        decoded: DecodedDetections,
        state: SensorState,
        arrival: Arrival,
        flagged: bool,
        fresh: bool,
        times: tuple[float, float],
    ) -> None:
        """A sensor's frame, decoded and checked, through its own tracker: ordering rules,
        step, the finite guard, the id reservation, publish. ``times``: when its handling
        began and when its decoding ended (perf_counter)."""
        t0, t1 = times
        ctx, m = self.ctx, self.ctx.metrics
        vehicle, sensor = state.vehicle, state.sensor
        frame = decoded.frame
        seq, stamp_ns = frame.seq, frame.stamp_ns
        bridged = False
        if not fresh:
            verdict = check_order(state.last, arrival, self.rules, state.before)
            if verdict.order is Order.UNDO_LAST:
                self._undo(state, arrival)
                verdict = check_order(state.last, arrival, self.rules)
            if verdict.reason is not None:
                r = Rejection(verdict.reason, verdict.field, verdict.detail, seq, stamp_ns)
                self._refuse(item, vehicle, sensor, r)
                return
            state.keep_undo()
            if verdict.order.resets:
                self._reset(state, verdict, seq, stamp_ns)
            elif verdict.order is Order.BRIDGE_GAP:
                bridged = True
                log.info(
                    "gap_bridged",
                    vehicle=vehicle,
                    sensor=sensor,
                    seq=seq,
                    gap_s=round((stamp_ns - (state.last_stamp_ns or stamp_ns)) * 1e-9, 3),
                )
        if flagged:
            state.implausible += 1

        stamp = state.tracker_stamp(stamp_ns)
        state.last_seen = time.monotonic()
        tframe, ignored = frame_from_wire(decoded, stamp)
        if bridged:  # the core re-associates what the prediction over the gap missed
            tframe = replace(tframe, after_gap=True)
        if ignored:
            m.boxes_ignored.inc(ignored)
        version = ctx.settings.tracks_schema_version
        fp = FloatingPointErrors()
        failed: str | None = None
        with fp:  # one block for the step and the conversion (each entry costs numpy calls)
            try:
                tracks = state.tracker.step(tframe)
            except Exception as e:
                log.error("tracker_failed", exc=True, vehicle=vehicle, sensor=sensor, seq=seq)
                failed = f"tracker: {e}"[:300]
            else:
                t2 = time.perf_counter()
                # The message's tracks map in one compiled call, with the finite guard's look
                # (None: uncompiled kernels). A frame it finds NaN or inf in goes the numpy
                # way: its casts raise the floating-point errors the event log has always
                # named, and the guard names the column.
                packed = pack_tracks_checked(tracks, state.id_base, ctx.classes, version)
                wire: TrackArrays | None = None
                body: TrackArrays | bytes
                if packed is None or packed[1] is not None:
                    body = wire = tracks_to_wire(tracks, state.id_base, ctx.classes)
                else:
                    body = packed[0]
        if failed is not None:
            state.before = None  # what keep_undo holds is no longer the state before the last
            r = Rejection(ErrorReason.INTERNAL_ERROR, None, failed, seq, stamp_ns)
            self._refuse(item, vehicle, sensor, r)
            return
        m.stages["track"].observe(t2 - t1)
        if not self._publishable(item, state, wire, fp, seq, stamp_ns):
            return
        self.sensors.reserve_ids(state)  # durable before any of the frame's ids leaves
        payload = encode_track_frame(
            vehicle=vehicle,
            sensor=sensor,
            seq=seq,
            stamp_ns=stamp_ns,
            frame_id=ctx.settings.world_frame_id if decoded.pose is not None else frame.frame_id,
            pose=frame.pose,
            key_frame=frame.key_frame,
            instance=ctx.settings.instance,
            received_ns=item.received_ns,
            published_ns=time.time_ns(),
            tracks=body,
            schema_version=version,
            epoch=state.epoch if version >= TRACK_EPOCH_SCHEMA_VERSION else None,
        )
        if not self._quiet:
            self.outbox.tracks(vehicle, sensor, payload)
        now_ns = time.time_ns()
        t3 = time.perf_counter()
        m.stages["publish"].observe(t3 - t2)
        m.observe_end_to_end(stamp_ns, item.received_ns, now_ns, vehicle)
        m.service_latency.observe((now_ns - item.received_ns) * 1e-9)
        m.count_tracked(vehicle)
        m.active_tracks.inc(state.tracked(arrival, len(tracks.ids)))
        if log.enabled(logging.DEBUG):  # not even the fields' cost otherwise
            log.debug(
                "frame_tracked",
                vehicle=vehicle,
                sensor=sensor,
                seq=seq,
                boxes=len(decoded.boxes),
                tracks=len(tracks.ids),
                ms=round((t3 - t0) * 1e3, 3),
            )

    def _plausible(
        self, vehicle: str, sensor: str, seq: int, decoded: DecodedDetections, item: Inbound
    ) -> bool:
        """Count (and log once per sensor and cause) what looks like a unit or convention
        mistake; the frame is tracked all the same. False for the member before this one
        counted and logged it (a replay at a takeover). True when something was found. The
        sensor's clock estimate learns from every frame that comes here."""
        frame = decoded.frame
        key = f"{vehicle}/{sensor}"
        clock = self._clocks.get(key)
        if clock is None:
            if len(self._clocks) >= _CLOCKS_CAP:
                del self._clocks[next(iter(self._clocks))]
            clock = self._clocks[key] = LeastLag()
        found = check_frame(
            decoded.boxes,
            frame.stamp_ns,
            item.received_ns,
            has_pose=decoded.pose is not None,
            codes=decoded.codes,
            thresholds=self.ctx.start_thresholds,
            key_frame=frame.key_frame,
            least_lag_ns=clock.see(frame.stamp_ns, item.received_ns),
            extents=decoded.extents,
        )
        if found:
            self._warn(vehicle, sensor, seq, found)
        return bool(found)

    def clock_lags(self) -> list[tuple[str, int]]:
        """From any thread (a scrape): (``vehicle/sensor``, its least receipt - stamp lately
        in ns) of each sensor heard in the last 20 s (plausibility.LeastLag)."""
        now = time.time_ns()
        return [(k, c.least) for k, c in list(self._clocks.items()) if c.fresh(now)]

    def _warn(self, vehicle: str, sensor: str, seq: int, found: list[Finding]) -> None:
        key = f"{vehicle}/{sensor}"
        if key not in self._warned and len(self._warned) >= _WARNED_CAP:
            self._warned.clear()  # sensor names come from the fleet: the memory stays bounded
        warned = self._warned.setdefault(key, set())
        for f in found:
            self.ctx.metrics.count_implausible(f.cause, vehicle)
            if f.cause not in warned:
                warned.add(f.cause)
                log.warning(
                    "implausible_frame",
                    vehicle=vehicle,
                    sensor=sensor,
                    seq=seq,
                    cause=f.cause.value,
                    likely=f.hint,
                    value=f.value,
                )

    def _undo(self, s: SensorState, frame: Arrival) -> None:
        """The last frame ran off the service's clock and this one, of the stream before
        it, agrees with it: forget the last frame rather than refuse or reset on its word."""
        undone, before = s.last, s.before
        self.ctx.metrics.active_tracks.inc(s.undo_last())
        lead = None if undone is None or before is None else lead_ns(before, undone)
        log.warning(
            "frame_undone",
            vehicle=s.vehicle,
            sensor=s.sensor,
            seq=frame.seq,
            undone_seq=None if undone is None else undone.seq,
            undone_lead_s=None if lead is None else round(lead * 1e-9, 3),
        )

    def _publishable(
        self,
        item: Inbound,
        s: SensorState,
        wire: TrackArrays | None,
        fp: FloatingPointErrors,
        seq: int,
        stamp_ns: int,
    ) -> bool:
        """The guard before publishing (docs/SERVICE.md, "What a fault can cost"): numpy's
        floating-point errors go to the log; a frame with NaN or inf is never published, and
        the tracker whose state produced it is reset (ids continue above the old ones).
        ``wire``: the columns, where the packing kernel found NaN or inf or did not run (None:
        it looked, and every value is finite)."""
        if fp.kinds:
            log.warning(
                "numeric_warning", vehicle=s.vehicle, sensor=s.sensor, seq=seq, kinds=fp.kinds
            )
        r = None if wire is None else non_finite_refusal(wire, seq, stamp_ns)
        if r is None:
            return True
        dropped_tracks = s.active_tracks
        s.reset(stamp_ns)
        self.ctx.metrics.resets.labels(reason="non_finite").inc()
        self.ctx.metrics.active_tracks.dec(dropped_tracks)
        log.error(
            "non_finite_tracks",
            vehicle=s.vehicle,
            sensor=s.sensor,
            seq=seq,
            field=r.field,
            id_base=s.id_base,
        )
        self._refuse(item, s.vehicle, s.sensor, r)
        return False

    def _reset(self, s: SensorState, verdict: Verdict, seq: int, stamp_ns: int) -> None:
        reason = verdict.order.value
        gap_s = (stamp_ns - (s.last_stamp_ns or stamp_ns)) * 1e-9
        dropped_tracks = s.active_tracks
        s.reset(stamp_ns)
        self.ctx.metrics.resets.labels(reason=reason).inc()
        self.ctx.metrics.active_tracks.dec(dropped_tracks)
        log.warning(
            "tracker_reset",
            vehicle=s.vehicle,
            sensor=s.sensor,
            seq=seq,
            reason=reason,
            jump_s=round(gap_s, 3),
            id_base=s.id_base,
        )

    # ------------------------------------------------------------------ refusals
    def _refuse(
        self,
        item: Inbound,
        vehicle: str,
        sensor: str,
        r: Rejection,
        counted: bool = False,
    ) -> None:
        """Count, announce and log a refusal (the announcer publishes it)."""
        if self._quiet:
            return  # the member before this one announced it
        if not counted:
            self.ctx.metrics.count_error(r.reason, vehicle)
        # A flood's refusals come by the thousand: another worker's frame goes first.
        self.ctx.trackers.pause(own=self.index)
        try:
            self.outbox.refuse(vehicle, sensor, r, item.received_ns)
        except ValueError as e:  # a notice that cannot be built: counted above, never a crash
            log.warning(
                "frame_rejected", key=item.key, reason=r.reason.value, unpublished=str(e)[:200]
            )

    def _announce(self, d: Dropped) -> None:
        """One notice for frames the queue gave up (counted when they were given up)."""
        vehicle, sensor = self.ctx.keys.sensor_of(d.key) or ("", "")
        if NAME_RE.match(vehicle) and NAME_RE.match(sensor):
            self.outbox.drops(vehicle, sensor, d.reason, d.seqs, d.stamp_ns, d.received_ns)

    def _drop(self, item: Inbound, reason: ErrorReason, counted: bool = False) -> None:
        """Report a frame shed under load (its header is read, nothing else)."""
        vehicle, sensor = self.ctx.keys.sensor_of(item.key) or ("", "")
        if not (NAME_RE.fullmatch(vehicle) and NAME_RE.fullmatch(sensor)):
            if not counted:
                self.ctx.metrics.count_error(reason, "")
            return
        self._refuse(item, vehicle, sensor, dropped(reason, item.payload), counted)


def _source_sn(item: Inbound) -> int | None:
    return item.source_sn
