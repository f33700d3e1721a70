"""The running service: wires Zenoh, the intake, the workers, snapshots and metrics together,
and owns the start-up and shutdown order.

Start: metrics HTTP → Zenoh session (a client started before its router waits for it, not
ready) → kernels (loaded from numba's cache, or compiled: tens of seconds, logged) → restore
snapshots → workers → subscriber, queryables, liveliness token → ready; until then /readyz's
503 says which step is under way. A client is ready only while it is connected to a router. Stop (SIGTERM/SIGINT): not ready → undeclare the subscriber (no new
frames) → workers finish their queues (bounded by ``shutdown_timeout_s``) and snapshot every
sensor → snapshot writer flushes → session closed → HTTP closed.
"""

from __future__ import annotations

import contextlib
import errno
import functools
import math
import signal
import threading
import time
from types import FrameType
from typing import Any

import msgpack
import zenoh
from zenoh import ext

from simpletrack.core import jit, solvers
from simpletrack.core.tracker import Tracker
from simpletrack.core.vehicle import Condition
from simpletrack.server.announcer import Announcer
from simpletrack.server.custody import Shared
from simpletrack.server.gil import Trackers
from simpletrack.server.group import Membership, Role, on_zenoh, undeclare
from simpletrack.server.heard import HeardStreams
from simpletrack.server.intake import (
    BurstBudget,
    Inbound,
    Intake,
    Kind,
    WorkQueue,
    depth,
    worker_index,
)
from simpletrack.server.logs import get_logger
from simpletrack.server.metrics import HttpEndpoint, Metrics, package_version
from simpletrack.server.misses import MissCounter
from simpletrack.server.outbox import MSGPACK, congestion_control, dropped, frame_error, put
from simpletrack.server.plausibility import StartThresholds
from simpletrack.server.sensor_tokens import SensorTokens
from simpletrack.server.sensors import SensorBudget
from simpletrack.server.settings import ServiceSettings, StandbyCopy, Subscribe, config_digest
from simpletrack.server.snapshots import SnapshotWriter, read_all, read_all_ids
from simpletrack.server.streams import Streams
from simpletrack.server.subscriptions import Subscriptions, TracksHandlers
from simpletrack.server.told import Told, read_told
from simpletrack.server.worker import NAME_RE, Context, Worker
from simpletrack.session import RouterWatch, open_session, open_session_waiting
from simpletrack.wire.codec import DecodeLimits, encode
from simpletrack.wire.header import peek_custody
from simpletrack.wire.keys import VEHICLE_STREAM, Keys
from simpletrack.wire.models import SensorStatus, ServiceStatus
from simpletrack.wire.reasons import STATUS_SCHEMA_VERSION, ErrorReason

log = get_logger("service")
# How long a starting member listens to the group's tokens before it takes frames: its
# first view then holds the members already there (tokens arrive within milliseconds).
SETTLE_S = 0.3
# Compiling every kernel (a cold numba cache: the first start after an install) measured
# 30-45 s on 2 busy cores; a warm cache loads them in ~1 s.
COMPILE_ALL_S = 40.0


class StartError(RuntimeError):
    """The service cannot start as configured (the message says why and what to change)."""


class Service:
    def __init__(self, settings: ServiceSettings) -> None:
        self.settings = settings
        self.keys = Keys(settings.prefix)
        self.config = settings.tracker_config()
        self.class_codes = {name: code for code, name in enumerate(self.config.class_names)}
        # Settings refuse an ignored class that the preset tracks, so this cannot shadow one.
        self.class_codes.update(dict.fromkeys(settings.ignore_classes, -1))
        self.metrics = Metrics(settings.metrics_vehicle_label, settings.metrics_max_vehicles)
        self.stop_requested = threading.Event()
        self.started_ns = time.time_ns()
        # Read once: the package's metadata is a file (0.8 ms a read, each status query's
        # largest cost under a query flood).
        self.version = package_version("simpletrack-service")
        self._ready = False
        # Why /readyz answers 503 while starting: the start-up step under way.
        self._phase = "starting"
        self._http: HttpEndpoint | None = None
        self._session: zenoh.Session | None = None
        self._writer: SnapshotWriter | None = None
        self._announcer: Announcer | None = None
        self._trackers = Trackers(settings.workers)  # which workers track a frame now
        self._workers: list[Worker] = []
        self._queues: list[WorkQueue] = []
        self._declared: list[Any] = []  # subscriber, queryables, token: undeclared in order
        self._client = settings.zenoh.options().is_client()
        self._routers: RouterWatch | None = None
        self.misses: MissCounter | None = None
        self.http_port: int | None = None
        self.membership = Membership(
            settings.instance,
            self.keys,
            enabled=settings.group,
            routers=self._routers_connected if self._client else None,
            on_change=self._on_members,
        )
        self.metrics.members.set(1)
        self.fusion = settings.fusion.config()
        self.membership.fuses = self.fusion is not None
        self.streams = Streams(
            self.keys,
            frozenset(settings.fusion.sensors),
            frozenset(settings.fusion.vehicles),
            gate=self.membership.fusion_gate,
        )
        self._shared: Shared | None = None
        self._subscriber: Any = None  # the detections subscriber: undeclared first at stop
        self._token: Any = None
        self._owned: Subscriptions | None = None  # subscribe = "owned"
        self._tokens: SensorTokens | None = None  # the sensors published (the same)
        self._handoff_queryables: list[Any] = []
        # How this member's name appears in its own tracks messages (msgpack key and value).
        self._own_instance = msgpack.packb("instance") + msgpack.packb(settings.instance)
        self._heard_streams = HeardStreams(self._own_instance)

    # ------------------------------------------------------------------ start
    def start(self) -> None:
        s = self.settings
        if s.metrics_port:
            self._http = self._bind_http()
            self._http.start()
            self.http_port = self._http.port
        session = self._open_session()
        if session is None:
            return  # asked to stop while waiting for the router
        self._session = session
        self._routers = RouterWatch(session, self._on_router_change)
        self.metrics.routers.set_function(self._routers_connected)
        if s.state_dir is not None:
            s.state_dir.mkdir(parents=True, exist_ok=True)
            self._writer = SnapshotWriter()
        solvers.preload()  # the first frame of an optimal matcher must not pay the import
        self._load_kernels()  # nor the first frame the kernels' compile
        digest = config_digest(self.config)
        self._shared = shared = Shared(
            membership=self.membership,
            session=session,
            keys=self.keys,
            metrics=self.metrics,
            instance=s.instance,
            digest=digest,
            handoff_timeout_s=s.handoff_timeout_s,
            checkpoint_frames=s.checkpoint_frames,
            checkpoint_max_age_s=s.checkpoint_max_age_s,
            heard=self._heard_streams,
        )
        if s.group:
            self.membership.start(session)
            if s.subscribe is Subscribe.OWNED:
                # With the members' tokens: the sensors' tokens out already arrive in the
                # settle time, before the mark past which a sensor is new to the fleet.
                self._tokens = SensorTokens(session, self.keys)
                self._tokens.start(plain=True)
                shared.fresh = self._tokens.claim_fresh
            # Whose tracks planners already have: a takeover publishes only past them. A
            # stream's owner tells its standby (server/told.py); the tracks themselves are
            # heard per stream ("owned", server/subscriptions.py) or all ("wide").
            self._declared.append(
                session.declare_subscriber(self.keys.told(s.instance), on_zenoh(self._on_told))
            )
            if s.subscribe is Subscribe.WIDE:
                self._declared.append(
                    session.declare_subscriber(self.keys.all_tracks, on_zenoh(self._on_tracks))
                )
                if self.fusion is not None:
                    self._declared.append(
                        session.declare_subscriber(
                            self.keys.all_vehicle_tracks, on_zenoh(self._on_vehicle_tracks)
                        )
                    )
            self.stop_requested.wait(SETTLE_S)
            if self.membership.twin:
                raise StartError(
                    f"instance {s.instance!r} is already live on prefix {s.prefix!r} (its "
                    f"liveliness token is out): give each instance its own --instance"
                )
        # One budget for every queue of the member and the frames waiting on its takeovers:
        # a recovery burst is kept beyond the bounds (never shed) while it lasts
        # (docs/SERVICE.md, "Recovered frames are kept").
        self.burst = BurstBudget(s.burst_bytes)
        self.metrics.watch_burst(self.burst)
        # The workers' refusal notices, published from a thread of their own: a slow
        # subscriber of an errors key never holds a worker (server/announcer.py).
        announcer = Announcer(session, congestion_control(s.congestion_control), self.metrics)
        self._announcer = announcer
        announcer.start()
        ctx = Context(
            settings=s,
            session=session,
            keys=self.keys,
            metrics=self.metrics,
            tracker_config_digest=digest,
            new_tracker=lambda: Tracker(self.config),
            class_codes=self.class_codes,
            classes=self.config.class_names,
            budget=SensorBudget(s.max_sensors),
            writer=self._writer,
            shared=shared,
            announcer=self._announcer,
            trackers=self._trackers,
            limits=DecodeLimits(max_bytes=s.max_frame_bytes, max_boxes=s.max_boxes),
            start_thresholds=StartThresholds.of(self.config),
            streams=self.streams,
            tracker_config=self.config,
            fusion=self.fusion,
            per_sensor_output=s.fusion.per_sensor_output,
            vehicle_frame_id=s.fusion.vehicle_frame_id,
            burst=self.burst,
        )
        self._queues = [
            WorkQueue(s.queue_size, budget=self.burst, catchup_after_s=s.catchup_after_s)
            for _ in range(s.workers)
        ]
        self._workers = [Worker(i, q, ctx) for i, q in enumerate(self._queues)]
        if s.state_dir is not None:
            # Id reservations first: a sensor whose snapshot is damaged still has one.
            for vehicle, sensor, floor in read_all_ids(s.state_dir):
                self._worker_of(vehicle, sensor).sensors.restore_floor(vehicle, sensor, floor)
            # Each stream's snapshot is taken up at its first frame, as a takeover: another
            # member may hold it, fresher (then used only if none does); alone, the gap
            # since the snapshot is replayed from the vehicle's cache first.
            for snap in read_all(s.state_dir):
                self._worker_of(snap.vehicle, snap.sensor).custody.machine.restart([snap])
        self._metrics_functions()
        for w in self._workers:
            w.start()

        intake = Intake(
            self._queues,
            s.backpressure,
            self._on_received,
            self._on_dropped,
            wanted=self._wanted if s.group else None,
            route=self.streams.route,
            trackers=self._trackers,
        )
        # A fused vehicle's stream keys end in the verbatim chunk @vehicle, which ``*``
        # does not match: each group key is declared for it too.
        streams = ["*", VEHICLE_STREAM] if self.fusion is not None else ["*"]
        if s.group:
            for name in streams:
                self._declared.append(
                    session.declare_subscriber(
                        self.keys.checkpoint(s.instance, "*", name),
                        lambda sample: self._on_checkpoint(intake, sample),
                    )
                )
            self._handoff_queryables = [
                session.declare_queryable(
                    self.keys.handoff(s.instance, "*", name), self._on_handoff_query
                )
                for name in streams
            ]
        self.misses = misses = MissCounter(intake, self.keys, self.metrics, s.instance, announcer)
        if self._tokens is not None:
            self._owned = Subscriptions(
                session,
                self.keys,
                self.membership,
                self._tokens,
                lambda: intake.handler(misses),
                misses.on_miss,
                s.history_frames,
                stream_of=self.streams.stream,
                tracks=TracksHandlers(self._on_tracks, self._on_vehicle_tracks),
                intake=intake,
                on_lost=lambda v, n, k: misses.announce(
                    v, n, k, "of a plain publisher's first burst, past what the scout keeps"
                ),
                idle_s=s.sensor_idle_s,
                standby_frames=s.standby is StandbyCopy.FRAMES,
                fuses_later=lambda v, n: (
                    self.streams.configured(v, n) and not self.streams.fusing()
                ),
            )
            self._owned.start()
            self._owned.settle(timeout=5.0)  # this member's share subscribed before its token
        else:
            # Recovery asks a vehicle's cache for the frames a gap (or its heartbeat) shows
            # were missed and holds that vehicle's later frames until they come: order kept.
            subscriber = ext.declare_advanced_subscriber(
                session,
                self.keys.all_detections,
                intake.handler(misses),
                # Without a cap, a service that first hears a vehicle's heartbeat takes its
                # whole cache: frames a restored sensor already tracked, up to seconds old.
                history=ext.HistoryConfig(max_samples=s.history_frames),
                recovery=ext.RecoveryConfig(heartbeat=True, periodic_queries=None),
            )
            self._subscriber = (
                subscriber.sample_miss_listener(on_zenoh(misses.on_miss)),
                subscriber,
            )
        self._declared.append(
            session.declare_queryable(self.keys.status(s.instance), self._on_status_query)
        )
        for name in streams:
            self._declared.append(
                session.declare_queryable(
                    self.keys.snapshot(s.instance, "*", name), self._on_snapshot_query
                )
            )
        if self.fusion is not None and s.group:
            # Before the member's own token: no member may see it without its ability.
            self._declared.append(
                session.liveliness().declare_token(self.keys.fusion_token(s.instance))
            )
        self._token = session.liveliness().declare_token(self.keys.liveliness(s.instance))
        self.membership.declared = True
        if self._routers is not None:
            self._declared.append(self._routers)
        self._ready = True
        log.info(
            "service_started",
            instance=s.instance,
            version=self.version,
            prefix=s.prefix,
            mode=s.zenoh.mode.value,
            listen=",".join(s.zenoh.listen),
            connect=",".join(s.zenoh.connect),
            metrics_port=self.http_port,
            preset=s.preset,
            workers=s.workers,
            backpressure=s.backpressure.value,
            state_dir=str(s.state_dir) if s.state_dir else None,
            restored=sum(len(w.custody.machine.local) for w in self._workers),
            group=s.group,
            members=len(self.membership.members),
        )

    def _load_kernels(self) -> None:
        """Compile the core's kernels now, or load them from numba's on-disk cache (~1 s).
        A cold cache takes tens of seconds: said in the log, before and after, and on /readyz."""
        state = jit.cache_state()
        started = time.monotonic()
        if state.cold:
            self._phase = "compiling kernels (the first start after an install; cached after)"
            log.info(
                "compiling_kernels",
                kernels=state.cold,
                of=state.kernels,
                estimate_s=round(COMPILE_ALL_S * state.cold / state.kernels),
                cache=state.location,
                why="numba's cache holds no compiled code for them yet; later starts load it",
            )
        jit.preload()
        self._phase = "starting"
        seconds = round(time.monotonic() - started, 1)
        if state.cold:
            log.info("kernels_compiled", kernels=state.cold, seconds=seconds, cache=state.location)
        else:
            log.debug("kernels_loaded", kernels=state.kernels, seconds=seconds)

    def _bind_http(self) -> HttpEndpoint:
        s = self.settings
        try:
            return HttpEndpoint(
                self.metrics,
                s.metrics_host,
                s.metrics_port,
                self.ready,
                why_not=self.not_ready_reason,
            )
        except OSError as e:
            where = f"metrics port {s.metrics_port} on {s.metrics_host}"
            if e.errno == errno.EADDRINUSE:
                # The usual cause: a second serve on one host with the default port.
                raise StartError(
                    f"{where} is in use (another simpletrack serve?): give this one "
                    f"--metrics-port (0: no HTTP endpoint)"
                ) from None
            raise StartError(f"{where}: cannot bind ({e.strerror or e})") from None

    def _open_session(self) -> zenoh.Session | None:
        options = self.settings.zenoh.options()
        if not (self._client and self.settings.wait_for_router):
            return open_session(options)
        log.info("waiting_for_router", connect=",".join(options.connect))
        self._phase = f"waiting for a Zenoh router ({','.join(options.connect)})"
        session = open_session_waiting(options, self.stop_requested)
        if session is not None:
            self._phase = "starting"
            log.info("router_reached", connect=",".join(options.connect))
        return session

    def _routers_connected(self) -> int:
        return self._routers.routers if self._routers is not None else 0

    def _on_router_change(self, connected: bool, router: str) -> None:
        self.membership.router_changed(connected)
        at = time.monotonic() if connected else None
        for w in self._workers:
            w.connected_at = at
        if connected:
            log.info("router_connected", router=router, routers=self._routers_connected())
        else:
            self.metrics.router_losses.inc()
            log.warning("router_lost", router=router, routers=self._routers_connected())

    def _metrics_functions(self) -> None:
        m = self.metrics
        m.queue_depth.set_function(lambda: depth(self._queues))
        m.standby_sensors.set_function(lambda: self._standby_count())
        for condition in Condition:
            m.fusion_sensors.labels(condition=condition.value).set_function(
                functools.partial(self._fused_sensors, condition)
            )
        if self.settings.state_dir is None:
            m.snapshot_age.set(math.nan)  # no persistence configured
        else:
            workers = self._workers
            m.snapshot_age.set_function(
                lambda: time.monotonic() - min(w.sensors.snapshot_done_at for w in workers)
            )

    def ready(self) -> bool:
        if not self._ready or self._session is None or self._session.is_closed():
            return False
        # A client without a router receives nothing: not ready, so that traffic and alerts
        # see the outage.
        return not self._client or self._routers_connected() > 0

    def not_ready_reason(self) -> str:
        """Why ``ready()`` is false (the body of /readyz's 503)."""
        if not self._ready:
            return "stopping" if self.stop_requested.is_set() else self._phase
        if self._session is None or self._session.is_closed():
            return "the Zenoh session is closed"
        return "no Zenoh router connected (client mode)"

    def _worker_of(self, vehicle: str, sensor: str) -> Worker:
        """The worker a stream's frames go to (the intake's routing: a fused sensor's
        vehicle's)."""
        key = self.streams.route(self.keys.detections(vehicle, sensor))
        return self._workers[worker_index(key, len(self._workers))]

    # ------------------------------------------------------------------ the group
    def _fused_sensors(self, condition: Condition) -> int:
        return sum(
            1
            for w in self._workers
            for v in w.sensors.vehicles()
            for r in v.tracker.records.values()
            if r.condition is condition
        )

    def _standby_count(self) -> int:
        return sum(w.custody.machine.standby_count() for w in self._workers)

    def _on_members(self, before: frozenset[str], after: frozenset[str]) -> None:
        self.metrics.members.set(len(after))
        if self._owned is not None:
            self._owned.changed()
        self._forget_messages()
        for w in self._workers:
            w.group_changed()

    def _forget_messages(self) -> None:
        """The group changed: the newest messages kept of streams this member neither owns
        nor stands by for now go (no failover of theirs comes here), so what it keeps is
        its current streams' messages, not every stream it ever stood by for."""
        role = self.membership.role
        self._heard_streams.forget_payloads(lambda stream: role(stream) is not Role.NONE)

    def _wanted(self, key: str) -> bool:
        """Zenoh callback, every frame: only frames of sensors this member owns or stands
        by for go on; the others are counted (the price of the wide subscription)."""
        names = self.keys.sensor_of(key)
        if names is None or self.membership.role(self.streams.stream(*names)) is not Role.NONE:
            return True
        self.metrics.not_owned.inc()
        return False

    def _on_tracks(self, sample: zenoh.Sample) -> None:
        """Tracks frames of sensors this member owns or stands by for: how far planners
        have them, and the ids they hold (a takeover neither repeats nor reuses them); read
        in batches (server/heard.py)."""
        heard = self._heard_stream(sample)
        if heard is not None:
            self._heard_streams.add(*heard)

    def _on_vehicle_tracks(self, sample: zenoh.Sample) -> None:
        """A fused vehicle's tracks: as ``_on_tracks``, and the vehicle's message seq."""
        heard = self._heard_stream(sample)
        if heard is not None:
            self._heard_streams.add(*heard, vehicle=True)

    def _on_told(self, sample: zenoh.Sample) -> None:
        """An owner's word of a tracks message it published on a stream this member stands
        by for (server/told.py); one for a stream held here is another member's claim."""
        try:
            words = read_told(sample.payload.to_bytes())
            if not words or self._shared is None or len(self.membership.members) <= 1:
                return
            for told in words:
                self._told(told)
        except Exception:  # a Zenoh callback never raises into Zenoh
            log.error("told_unreadable", exc=True, key=str(sample.key_expr))

    def _told(self, told: Told) -> None:
        stream = told.stream
        if told.instance == self.settings.instance or self.membership.role(stream) is Role.NONE:
            return
        if self._workers:
            worker = self._worker_of(told.vehicle, told.sensor)
            held = worker.sensors.get(stream)
            if held is not None:
                self._supersede_if_newer(worker, stream, held.epoch, told.instance, told.epoch)
                return
        self._heard_streams.told(told)

    def _heard_stream(self, sample: zenoh.Sample) -> tuple[str, bytes] | None:
        """The stream of a tracks sample worth learning from, and the payload (copied out
        once): one this member owns or stands by for and does not hold (another member's
        with a higher epoch fences it). Decided as it comes: what is held changes."""
        names = self.keys.sensor_of(str(sample.key_expr))
        if names is None or self._shared is None or len(self.membership.members) <= 1:
            return None  # alone, the only tracks are this member's own
        stream = f"{names[0]}/{names[1]}"
        if self.membership.role(stream) is Role.NONE:
            return None
        payload = sample.payload.to_bytes()
        # Heard from the start of the settle time on, before the workers exist (none holds
        # a sensor yet then).
        if self._workers:
            worker = self._worker_of(*names)
            held = worker.sensors.get(stream)
            if held is not None:
                self._fence_if_superseded(worker, stream, held.epoch, payload)
                return None
        return stream, payload

    def _fence_if_superseded(self, worker: Worker, stream: str, epoch: int, payload: bytes) -> None:
        """A stream held here, heard from another member with a higher custody epoch: that
        member took it over while this one could not see it; this one's state is stale."""
        if self._own_instance in payload:
            return  # this member's own message: the usual case, no parse
        self._supersede_if_newer(worker, stream, epoch, *peek_custody(payload))

    def _supersede_if_newer(
        self, worker: Worker, stream: str, epoch: int, instance: str | None, theirs: int | None
    ) -> None:
        """Another member published ``stream`` (or told its standby so) with a higher custody
        epoch than the one held here: this member's state is stale."""
        if instance != self.settings.instance and theirs is not None and theirs > epoch:
            worker.supersede(stream)

    def _on_checkpoint(self, intake: Intake, sample: zenoh.Sample) -> None:
        names = self.keys.service_sensor_of(str(sample.key_expr))
        if names is not None and _stream_names(*names):
            intake.checkpoint(sample, self.keys.detections(*names))

    def _on_handoff_query(self, query: zenoh.Query) -> None:
        """A member that owns a sensor in its view asks for it: the worker holding it
        releases it and answers its exact state (after the workers stopped: answered here)."""
        names = self.keys.service_sensor_of(str(query.key_expr))
        asker = query.parameters.get("from")
        if (
            names is None
            or not _stream_names(*names)
            or asker is None
            or asker == self.settings.instance
        ):
            query.drop()  # type: ignore[no-untyped-call]
            return
        vehicle, sensor = names
        worker = self._worker_of(vehicle, sensor)
        reply_key = self.keys.handoff(self.settings.instance, vehicle, sensor)

        key = f"{vehicle}/{sensor}"
        if worker.sensors.get(key) is None and key not in worker.custody.released:
            query.drop()  # type: ignore[no-untyped-call]
            return  # the usual answer, at once: not held here
        try:
            # The worker's lock, not its queue: at most one frame's wait, and no cycle (a
            # worker never holds it while asking a member).
            with worker.lock:
                snap = worker.custody.release(vehicle, sensor, asker)
            if snap is not None:
                query.reply(reply_key, encode(snap), encoding=MSGPACK)
        except zenoh.ZError as e:
            log.warning("query_reply_failed", key=reply_key, error=str(e))
        finally:
            query.drop()  # type: ignore[no-untyped-call]

    # ------------------------------------------------------------------ callbacks
    def _on_received(self, key: str) -> None:
        vehicle, _ = self.keys.sensor_of(key) or ("", "")
        self.metrics.count_received(vehicle)

    def _on_dropped(self, item: Inbound, reason: ErrorReason) -> None:
        """Runs in the Zenoh callback: count now; queue-full notices are published by the
        worker; a frame refused at shutdown is reported here (no worker will see it)."""
        vehicle, sensor = self.keys.sensor_of(item.key) or ("", "")
        self.metrics.count_error(reason, vehicle)
        if item.kind is Kind.CHECKPOINT:
            return  # the next checkpoint supersedes it: nothing a planner waits for
        if reason is ErrorReason.DROPPED_SHUTDOWN and self._session is not None:
            if NAME_RE.fullmatch(vehicle) and NAME_RE.fullmatch(sensor):
                r = dropped(reason, item.payload)
                err = frame_error(vehicle, sensor, r, self.settings.instance, item.received_ns)
                with contextlib.suppress(zenoh.ZError):
                    # DROP whatever the setting: a Zenoh callback must never block.
                    put(
                        self._session,
                        self.keys.errors(vehicle, sensor),
                        encode(err),
                        zenoh.CongestionControl.DROP,
                    )
            log.warning("frame_dropped", vehicle=vehicle, sensor=sensor, reason=reason.value)

    def status(self, only: tuple[str, str] | None = None) -> ServiceStatus:
        """The service's status; ``only`` (vehicle, sensor) keeps that sensor's entry alone
        (what a resuming publisher asks for: its last processed seq)."""
        sensors = [st for w in self._workers for st in w.sensors.status()]
        # Restored from disk, not taken up yet (no frame since the start): where they stand.
        sensors += [
            SensorStatus(
                vehicle=snap.vehicle,
                sensor=snap.sensor,
                last_seq=snap.last_seq,
                last_stamp_ns=snap.last_stamp_ns,
                frames=snap.frames,
                active_tracks=0,
                idle_s=round((time.time_ns() - snap.written_ns) * 1e-9, 3),
                rate_hz=0.0,
                resets=0,
                implausible_frames=0,
            )
            for w in self._workers
            for snap in list(w.custody.machine.local.values())
            if snap.sensor != VEHICLE_STREAM
        ]
        now = time.monotonic()
        vehicles = []
        for v in (v for w in self._workers for v in w.sensors.vehicles()):
            entry, fused = v.status(now)
            vehicles.append(entry)
            sensors += fused
        if only is not None:
            sensors = [st for st in sensors if (st.vehicle, st.sensor) == only]
            vehicles = [v for v in vehicles if v.vehicle == only[0]]
        return ServiceStatus(
            schema_version=STATUS_SCHEMA_VERSION,
            instance=self.settings.instance,
            version=self.version,
            preset=self.settings.preset,
            classes=list(self.config.class_names),
            config_digest=config_digest(self.config),
            started_ns=self.started_ns,
            ready=self.ready(),
            queue_depth=depth(self._queues),
            sensors=sensors,
            members=sorted(self.membership.members),
            standby_sensors=self._standby_count(),
            vehicles=vehicles,
            **(dict[str, Any](self._shared.counts) if self._shared is not None else {}),
        )

    def _on_status_query(self, query: zenoh.Query) -> None:
        params = query.parameters
        vehicle, sensor = params.get("vehicle"), params.get("sensor")
        only = (vehicle, sensor) if vehicle is not None and sensor is not None else None
        self._trackers.pause()  # a query flood: the frames being tracked go first
        try:
            query.reply(
                self.keys.status(self.settings.instance),
                encode(self.status(only)),
                encoding=MSGPACK,
            )
        except zenoh.ZError as e:
            log.warning("query_reply_failed", key=str(query.key_expr), error=str(e))
        finally:
            query.drop()  # type: ignore[no-untyped-call]

    def _on_snapshot_query(self, query: zenoh.Query) -> None:
        """Each worker serialises its own sensors on its own thread, taking queries in turn
        with its sensors' frames (at most ``MAX_QUERIES`` waiting: beyond, an error reply);
        the last to answer finalises the query."""
        asked = zenoh.KeyExpr(str(query.key_expr))
        parts = str(query.key_expr).split("/")
        vehicle, sensor = parts[-2], parts[-1]
        if _stream_names(vehicle, sensor):
            targets = [self._worker_of(vehicle, sensor)]
        else:
            targets = list(self._workers)
        pending = [len(targets)]
        busy: list[int] = []  # workers whose query lane was full
        lock = threading.Lock()
        instance = self.settings.instance

        def done(refused: int | None = None) -> None:
            with lock:
                if refused is not None:
                    busy.append(refused)
                pending[0] -= 1
                last = pending[0] == 0
            if not last:
                return
            if busy:
                # Bounded lanes: the querier learns at once that part of the answer is missing.
                self.metrics.queries_refused.inc()
                with contextlib.suppress(zenoh.ZError):
                    query.reply_err(f"busy: workers {sorted(busy)} have queries waiting")
            query.drop()  # type: ignore[no-untyped-call]

        def answer(worker: Worker) -> None:
            try:
                for v, s in worker.sensors.names():
                    key = self.keys.snapshot(instance, v, s)
                    if zenoh.KeyExpr(key).intersects(asked):
                        snap = worker.sensors.snapshot_of(v, s)
                        if snap is not None:
                            query.reply(key, encode(snap), encoding=MSGPACK)
            except zenoh.ZError as e:
                log.warning("query_reply_failed", key=str(asked), error=str(e))
            finally:
                done()

        for w in targets:
            if not w.queue.put_control(lambda w=w: answer(w)):  # type: ignore[misc]
                done(refused=w.index)
                self._trackers.pause()  # a query flood: the frames being tracked go first

    # ------------------------------------------------------------------ stop
    def request_stop(self, signum: int | None = None, _frame: FrameType | None = None) -> None:
        self.stop_requested.set()

    def shutdown(self) -> None:
        """Stop taking frames, finish the queued ones, then leave the group: the members
        taking this one's sensors ask for them (or read the final checkpoints) while it
        still answers; only then close."""
        s = self.settings
        self._ready = False
        self._phase = "stopping"
        log.info("service_stopping", instance=s.instance)
        if self._subscriber is not None:
            undeclare(*self._subscriber)
            self._subscriber = None
        if self._owned is not None:
            self._owned.close()
        if self._tokens is not None:
            self._tokens.close()  # a start stopped before its subscriptions (a twin)
        deadline = time.monotonic() + s.shutdown_timeout_s
        for w in self._workers:
            w.drain_deadline = deadline
            w.queue.close()
        for w in self._workers:
            if w.is_alive():
                w.join(max(0.1, deadline - time.monotonic() + 5.0))
            if w.is_alive():
                log.error("worker_stuck", worker=w.index)
            else:  # it publishes no more: its unused reserved ids can go back
                w.sensors.release_ids()
        if self._announcer is not None:  # the workers' last notices, then no more
            self._announcer.close(max(1.0, deadline - time.monotonic()))
        if self._token is not None:
            undeclare(self._token)
            self._token = None
        self._await_handoffs()
        undeclare(*self._handoff_queryables)
        self._handoff_queryables = []
        undeclare(*self._declared)
        self._declared.clear()
        self.membership.close()
        if self._writer is not None and not self._writer.close(timeout=s.shutdown_timeout_s):
            log.error("snapshot_writer_stuck")
        if self._session is not None:
            self._session.close()  # type: ignore[no-untyped-call]
        if self._http is not None:
            self._http.close()
        log.info(
            "service_stopped",
            instance=s.instance,
            sensors=sum(len(w.sensors) for w in self._workers),
        )

    def _await_handoffs(self) -> None:
        """Until every sensor held here was asked for, or ``handoff_timeout_s``."""
        if not self.settings.group or len(self.membership.members) <= 1:
            return
        deadline = time.monotonic() + self.settings.handoff_timeout_s
        held = sum(len(w.sensors) for w in self._workers)
        while held and time.monotonic() < deadline:
            time.sleep(0.02)
            held = sum(len(w.sensors) for w in self._workers)
        log.info("handoffs_done" if not held else "handoffs_timed_out", left_with_standby=held)


def _stream_names(vehicle: str, sensor: str) -> bool:
    """A stream's names: a sensor's, or a fused vehicle's (``@vehicle``)."""
    return bool(NAME_RE.fullmatch(vehicle)) and (
        sensor == VEHICLE_STREAM or bool(NAME_RE.fullmatch(sensor))
    )


def run(settings: ServiceSettings) -> int:
    """Run until SIGTERM/SIGINT, then shut down cleanly. Returns the exit code."""
    service = Service(settings)
    previous = {
        sig: signal.signal(sig, service.request_stop) for sig in (signal.SIGTERM, signal.SIGINT)
    }
    try:
        service.start()
        while not service.stop_requested.wait(0.5):
            pass
    finally:
        service.shutdown()
        for sig, handler in previous.items():
            signal.signal(sig, handler)
    return 0


__all__ = ["Service", "StartError", "run"]
