"""Prometheus metrics and the HTTP endpoint serving /metrics, /healthz and /readyz.

Label cardinality is bounded: ``reason``, ``stage`` and ``cause`` are enums; ``vehicle`` only when
enabled, and capped (later vehicles share ``_other``); never a track id, and a sensor only in
``simpletrack_clock_offset_seconds``, for at most ten sensors whose clocks are off. No
``_created`` series: a counter or histogram is its samples alone.
"""

from __future__ import annotations

import platform
import threading
from collections.abc import Callable
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from importlib.metadata import PackageNotFoundError, version
from typing import TYPE_CHECKING, Any

from prometheus_client import (
    CONTENT_TYPE_LATEST,
    CollectorRegistry,
    Counter,
    Gauge,
    Histogram,
    Info,
    ProcessCollector,
    disable_created_metrics,
    generate_latest,
)
from prometheus_client.core import CounterMetricFamily, GaugeMetricFamily, Metric
from prometheus_client.registry import Collector

from simpletrack.core.vehicle import Condition
from simpletrack.server.plausibility import Cause
from simpletrack.server.sensors import CLOCK_TOLERANCE_S
from simpletrack.wire.reasons import DROP_REASONS, SCHEMA_VERSION, ErrorReason

if TYPE_CHECKING:
    from collections.abc import Iterable

    from simpletrack.server.intake import BurstBudget

# Frame latencies live between ~0.1 ms (decode) and seconds (a stalled queue).
LATENCY_BUCKETS = (
    0.0001,
    0.00025,
    0.0005,
    0.001,
    0.0025,
    0.005,
    0.01,
    0.025,
    0.05,
    0.1,
    0.25,
    0.5,
    1.0,
    2.5,
    5.0,
    10.0,
)
STAGES = ("queue", "decode", "track", "publish")
OTHER_VEHICLES = "_other"
CLOCK_SIDES = ("ahead", "behind")
# Sensors named in simpletrack_clock_offset_seconds: those off by more than the tolerance,
# furthest first, at most this many (the one series labelled by sensor: bounded this way).
CLOCK_SENSORS_SHOWN = 10

# Every counter and histogram would also export a ``<name>_created`` series (its creation
# time): twice the series for nothing a dashboard reads. Process-wide, before any is made.
disable_created_metrics()  # type: ignore[no-untyped-call]  # untyped in prometheus_client


def package_version(name: str) -> str:
    try:
        return version(name)
    except PackageNotFoundError:
        return "unknown"


class Metrics:
    """Every metric the service exports, on its own registry."""

    def __init__(self, vehicle_label: bool = False, max_vehicles: int = 100) -> None:
        self.registry = r = CollectorRegistry()
        self._vehicle_label = vehicle_label
        # (reason, vehicle label or "") -> its counter; bounded by reasons x max_vehicles.
        self._error_children: dict[tuple[ErrorReason, str], Any] = {}
        self._max_vehicles = max_vehicles
        self._vehicles: set[str] = set()
        v: tuple[str, ...] = ("vehicle",) if vehicle_label else ()
        self.received = Counter(
            "simpletrack_frames_received", "Detection frames taken off Zenoh", v, registry=r
        )
        self.tracked = Counter(
            "simpletrack_frames_tracked", "Frames tracked and published", v, registry=r
        )
        self.rejected = Counter(
            "simpletrack_frames_rejected",
            "Frames refused, by reason (also published on the errors key)",
            ("reason", *v),
            registry=r,
        )
        self.dropped = Counter(
            "simpletrack_frames_dropped",
            "Frames shed under load or missed in transport, by reason (also published on the errors key)",
            ("reason", *v),
            registry=r,
        )
        self.error_notices_dropped = Counter(
            "simpletrack_error_notices_dropped",
            "Refusal notices never published on an errors key: past the announcer's backlog "
            "(a slow errors subscriber) or still waiting at the stop; their frames are counted "
            "as rejected or dropped all the same",
            registry=r,
        )
        self.error_notices_waiting = Gauge(
            "simpletrack_error_notices_waiting",
            "Refusal notices (and tracks held behind them) waiting for the announcer to publish them",
            registry=r,
        )
        self.stage = Histogram(
            "simpletrack_stage_seconds",
            "Time per frame in each stage: queue wait, decode, track, publish",
            ("stage",),
            buckets=LATENCY_BUCKETS,
            registry=r,
        )
        self.end_to_end = Histogram(
            "simpletrack_end_to_end_seconds",
            "Sensor stamp_ns to tracks published (needs clocks in sync with the sensors; "
            "frames stamped ahead of the service's clock are not in it)",
            buckets=LATENCY_BUCKETS,
            registry=r,
        )
        self.clock_ahead = Counter(
            "simpletrack_clock_ahead_frames",
            "Frames stamped ahead of the service's clock at receipt (a sensor clock ahead, or "
            "a replay): tracked, but no latency of theirs is in simpletrack_end_to_end_seconds",
            v,
            registry=r,
        )
        self.service_latency = Histogram(
            "simpletrack_service_latency_seconds",
            "Frame received by the service to tracks published",
            buckets=LATENCY_BUCKETS,
            registry=r,
        )
        self.queue_depth = Gauge(
            "simpletrack_queue_depth", "Frames waiting in the worker queues", registry=r
        )
        self.active_sensors = Gauge(
            "simpletrack_active_sensors", "Sensors with tracker state in memory", registry=r
        )
        self.active_tracks = Gauge(
            "simpletrack_active_tracks", "Tracks reported on each sensor's latest frame", registry=r
        )
        self.snapshot_age = Gauge(
            "simpletrack_snapshot_age_seconds",
            "Seconds since the last complete snapshot (since start if none yet; NaN: no state_dir)",
            registry=r,
        )
        self.snapshots = Counter(
            "simpletrack_snapshots_written", "Sensor snapshot files written", registry=r
        )
        self.snapshot_failures = Counter(
            "simpletrack_snapshot_failures",
            "Sensor snapshots that could not be written",
            registry=r,
        )
        self.restored = Counter(
            "simpletrack_sensors_restored", "Sensors restored from the state directory", registry=r
        )
        self.evicted = Counter(
            "simpletrack_sensors_evicted", "Sensors evicted after sensor_idle_s", registry=r
        )
        self.reclaimed = Counter(
            "simpletrack_sensors_reclaimed",
            "Sensors evicted early, silent over reset_gap_s while every max_sensors slot was taken",
            registry=r,
        )
        self.queries_refused = Counter(
            "simpletrack_queries_refused",
            "Snapshot queries answered with an error: a worker already had its queries waiting",
            registry=r,
        )
        self.resets = Counter(
            "simpletrack_tracker_resets",
            "Per-sensor tracker resets: gap, time_backwards, restart, non_finite (tracks not published)",
            ("reason",),
            registry=r,
        )
        self.boxes_ignored = Counter(
            "simpletrack_boxes_ignored", "Boxes of classes listed in ignore_classes", registry=r
        )
        self.routers = Gauge(
            "simpletrack_zenoh_routers",
            "Zenoh routers this service is connected to now (client mode: 0 means not ready)",
            registry=r,
        )
        self.router_losses = Counter(
            "simpletrack_zenoh_router_disconnects",
            "Times a connection to a Zenoh router was lost",
            registry=r,
        )
        # The group (docs/SCALE.md)
        self.members = Gauge(
            "simpletrack_group_members",
            "Live instances on this prefix, this one included (its view)",
            registry=r,
        )
        self.standby_sensors = Gauge(
            "simpletrack_standby_sensors",
            "Sensors this instance stands by for (keeps their checkpoints, and recent frames where it hears them)",
            registry=r,
        )
        self.handoffs = Counter(
            "simpletrack_handoffs",
            "Sensors handed over between live instances with their exact state",
            ["direction"],
            registry=r,
        )
        self.failovers = Counter(
            "simpletrack_failovers",
            "Sensors taken over from a member gone without handing them over (from its checkpoint)",
            registry=r,
        )
        self.fences = Counter(
            "simpletrack_fences",
            "Streams this member stopped publishing from its own state (why: stopped, its "
            "process stopped past fence_after_s; superseded, a higher epoch heard)",
            ["why"],
            registry=r,
        )
        self.replayed = Counter(
            "simpletrack_replayed_frames",
            "Frames tracked again at a takeover, after the state it started from",
            registry=r,
        )
        self.restart_refills = Counter(
            "simpletrack_restart_refills",
            "Restarted publishers whose first frame heard was not their first: the vehicle's "
            "cache was asked for the frames before it",
            registry=r,
        )
        self.republished = Counter(
            "simpletrack_tracks_republished",
            "Tracks messages a failover published again as this member's: the dead owner's "
            "last, which its checkpoint held (a kill may have cut that put short)",
            registry=r,
        )
        self.not_owned = Counter(
            "simpletrack_frames_not_owned",
            "Detection frames heard for sensors of other members, dropped before decoding",
            registry=r,
        )
        self.checkpoints_sent = Counter(
            "simpletrack_checkpoints_sent",
            "Sensor states sent to their standby member",
            registry=r,
        )
        self.checkpoint_bytes = Counter(
            "simpletrack_checkpoint_bytes",
            "Bytes of the sensor states sent to other members (checkpoints, pushed hand-offs)",
            registry=r,
        )
        for direction in ("in", "out"):
            self.handoffs.labels(direction=direction)
        self.fusion_frames = Counter(
            "simpletrack_fusion_frames",
            "Fused sensors' frames by what the vehicle's tracker did with them: applied, "
            "reprocessed (late, within history_s), late (refused), flagged (refused), "
            "verifying (watched only)",
            ("outcome",),
            registry=r,
        )
        for outcome in ("applied", "reprocessed", "late", "flagged", "verifying"):
            self.fusion_frames.labels(outcome=outcome)
        self.fusion_wait = Histogram(
            "simpletrack_fusion_wait_seconds",
            "Fused frames: receipt to release from the vehicle's reorder window",
            buckets=LATENCY_BUCKETS,
            registry=r,
        )
        self.fusion_sensors = Gauge(
            "simpletrack_fusion_sensors",
            "Fused sensors of the vehicles held here, by condition",
            ("condition",),
            registry=r,
        )
        for condition in Condition:  # every series from the start (the app sets each)
            self.fusion_sensors.labels(condition=condition.value)
        # By cause (an enum), never by sensor: the sensor is in the once-per-sensor log line
        # (docs/SERVICE.md, "Plausibility warnings").
        self.implausible = Counter(
            "simpletrack_implausible_frames",
            "Frames tracked although they look like a unit or convention mistake, by cause",
            ("cause", *v),
            registry=r,
        )
        # The burst budget (docs/SERVICE.md, "Recovered frames are kept"), read at each scrape
        # from the budget the service hands ``watch_burst`` (0 until then).
        self.burst: BurstBudget | None = None
        r.register(_BurstCollector(self))
        # Each worker's sensors' clock estimates (server/plausibility.py LeastLag), read at
        # each scrape: two figures per side, whatever the number of sensors.
        self.clock_sources: list[Callable[[], Iterable[tuple[str, int]]]] = []
        r.register(_ClockCollector(self))
        # CPU, resident memory, open fds: what a leak or a busy loop shows first (the
        # default registry has these; this one is our own). Empty off Linux.
        ProcessCollector(registry=r)
        self.build = Info("simpletrack_build", "Versions of this service", registry=r)
        self.build.info(
            {
                "version": package_version("simpletrack-service"),
                "schema_version": str(SCHEMA_VERSION),
                "zenoh": package_version("eclipse-zenoh"),
                "python": platform.python_version(),
            }
        )
        if not vehicle_label:  # make every reason visible at 0 from the first scrape
            for reason in ErrorReason:
                (self.dropped if reason in DROP_REASONS else self.rejected).labels(reason=reason)
        # Each stage's child, looked up once: a frame observes all four.
        self.stages = {stage: self.stage.labels(stage=stage) for stage in STAGES}
        for why in ("gap", "time_backwards", "restart", "non_finite"):
            self.resets.labels(reason=why)
        if not vehicle_label:
            for cause in Cause:
                self.implausible.labels(cause=cause.value)

    def labels(self, vehicle: str) -> dict[str, str]:
        """The vehicle label (if enabled), folding vehicles past the cap into ``_other``."""
        if not self._vehicle_label:
            return {}
        if vehicle not in self._vehicles:
            if len(self._vehicles) >= self._max_vehicles:
                return {"vehicle": OTHER_VEHICLES}
            self._vehicles.add(vehicle)
        return {"vehicle": vehicle}

    def count_received(self, vehicle: str) -> None:
        labels = self.labels(vehicle)
        (self.received.labels(**labels) if labels else self.received).inc()

    def count_tracked(self, vehicle: str) -> None:
        labels = self.labels(vehicle)
        (self.tracked.labels(**labels) if labels else self.tracked).inc()

    def count_missed(self, vehicle: str, n: int) -> None:
        self.dropped.labels(reason=ErrorReason.MISSED.value, **self.labels(vehicle)).inc(n)

    def observe_end_to_end(
        self, stamp_ns: int, received_ns: int, published_ns: int, vehicle: str
    ) -> None:
        """A tracked frame's stamp to its tracks published, in ``end_to_end``; a frame stamped
        ahead of the service's clock (received or published before its stamp) counts in
        ``clock_ahead`` instead: a negative interval is a clock's offset, not a latency."""
        if stamp_ns > received_ns or stamp_ns > published_ns:
            labels = self.labels(vehicle)
            (self.clock_ahead.labels(**labels) if labels else self.clock_ahead).inc()
        else:
            self.end_to_end.observe((published_ns - stamp_ns) * 1e-9)

    def watch_clocks(self, source: Callable[[], Iterable[tuple[str, int]]]) -> None:
        """Export the sensor clocks ``source`` estimates: (``vehicle/sensor``, its least
        receipt - stamp lately in ns) of each sensor a worker heard in the last 20 s."""
        self.clock_sources.append(source)

    def count_implausible(self, cause: Cause, vehicle: str) -> None:
        self.implausible.labels(cause=cause.value, **self.labels(vehicle)).inc()

    def count_error(self, reason: ErrorReason, vehicle: str) -> None:
        # On the intake's drop path for every frame a flood sheds: the labelled child is
        # looked up once (prometheus_client's labels() costs more than the whole increment).
        labels = self.labels(vehicle)
        key = (reason, labels.get("vehicle", ""))
        child = self._error_children.get(key)
        if child is None:
            metric = self.dropped if reason in DROP_REASONS else self.rejected
            child = self._error_children[key] = metric.labels(reason=reason.value, **labels)
        child.inc()

    def watch_burst(self, budget: BurstBudget) -> None:
        """Export the member's burst budget (its bytes in use, peak and limit, and the
        frames kept on it); its refusals are ``simpletrack_frames_dropped{reason="missed"}``."""
        self.burst = budget


class _BurstCollector(Collector):
    def __init__(self, metrics: Metrics) -> None:
        self._metrics = metrics

    def collect(self) -> Iterable[Metric]:
        b = self._metrics.burst
        yield GaugeMetricFamily(
            "simpletrack_burst_bytes",
            "Bytes of frames held beyond queue_size on the member's burst budget now "
            "(catch-up frames recovered or replayed, frames waiting on a takeover)",
            value=0 if b is None else b.in_use,
        )
        yield GaugeMetricFamily(
            "simpletrack_burst_bytes_peak",
            "The most bytes ever held at once on the burst budget",
            value=0 if b is None else b.peak,
        )
        yield GaugeMetricFamily(
            "simpletrack_burst_bytes_limit",
            "The burst budget (setting burst_bytes); a catch-up frame past it is dropped as missed",
            value=0 if b is None else b.limit,
        )
        yield CounterMetricFamily(
            "simpletrack_burst_frames",
            "Catch-up frames (and the frames of their burst behind them) kept beyond "
            "queue_size on the burst budget instead of being shed",
            value=0 if b is None else b.kept,
        )


class _ClockCollector(Collector):
    def __init__(self, metrics: Metrics) -> None:
        self._metrics = metrics

    def collect(self) -> Iterable[Metric]:
        tol = CLOCK_TOLERANCE_S * 1e9
        furthest, off = dict.fromkeys(CLOCK_SIDES, 0.0), dict.fromkeys(CLOCK_SIDES, 0.0)
        named: list[tuple[int, str]] = []
        for source in list(self._metrics.clock_sources):
            for sensor, lag in source():
                side = "ahead" if lag < 0 else "behind"
                furthest[side] = max(furthest[side], abs(lag) * 1e-9)
                if abs(lag) > tol:
                    off[side] += 1
                    named.append((lag, sensor))
        yield _by_side(
            GaugeMetricFamily(
                "simpletrack_clock_offset_max_seconds",
                "The sensor clock furthest from the service's, by side, over the sensors heard "
                "in the last 20 s: each sensor's least (receipt - stamp) of its frames of the "
                "last 10-20 s; ahead: its stamps lead the service's clock by at least this; "
                "behind: its clock offset plus its fastest delivery (0: none)",
                labels=["side"],
            ),
            furthest,
        )
        yield _by_side(
            GaugeMetricFamily(
                "simpletrack_clock_off_sensors",
                f"Sensors heard in the last 20 s whose clock is more than {CLOCK_TOLERANCE_S:g} s "
                f"ahead of or behind the service's (by the same estimate), by side",
                labels=["side"],
            ),
            off,
        )
        shown = GaugeMetricFamily(
            "simpletrack_clock_offset_seconds",
            f"Each sensor whose clock is more than {CLOCK_TOLERANCE_S:g} s off the service's "
            f"(the {CLOCK_SENSORS_SHOWN} furthest; all of them in simpletrack_clock_off_sensors): "
            "stamp - receipt by the same estimate, > 0 ahead, < 0 behind (offset plus delivery)",
            labels=["sensor"],
        )
        for lag, sensor in sorted(named, key=lambda n: (-abs(n[0]), n[1]))[:CLOCK_SENSORS_SHOWN]:
            shown.add_metric([sensor], -lag * 1e-9)
        yield shown


def _by_side(family: GaugeMetricFamily, values: dict[str, float]) -> Metric:
    for side in CLOCK_SIDES:
        family.add_metric([side], values[side])
    return family


class HttpEndpoint:
    """/metrics (Prometheus text), /healthz (process alive), /readyz (``ready()`` is true;
    503's body says ``why_not()``)."""

    def __init__(
        self,
        metrics: Metrics,
        host: str,
        port: int,
        ready: Callable[[], bool],
        why_not: Callable[[], str] | None = None,
    ) -> None:
        registry = metrics.registry

        class Handler(BaseHTTPRequestHandler):
            def do_GET(self) -> None:
                path = self.path.split("?", 1)[0]
                if path == "/metrics":
                    self._send(200, generate_latest(registry), CONTENT_TYPE_LATEST)
                elif path == "/healthz":
                    self._send(200, b"ok\n")
                elif path == "/readyz":
                    if ready():
                        self._send(200, b"ready\n")
                    else:
                        why = f": {why_not()}" if why_not is not None else ""
                        self._send(503, f"not ready{why}\n".encode())
                else:
                    self._send(404, b"not found: try /metrics, /healthz, /readyz\n")

            def _send(self, code: int, body: bytes, ctype: str = "text/plain") -> None:
                self.send_response(code)
                self.send_header("Content-Type", ctype)
                self.send_header("Content-Length", str(len(body)))
                self.end_headers()
                self.wfile.write(body)

            def log_message(self, format: str, *args: Any) -> None:
                pass  # scrapes every few seconds would drown the event log

        self._server = ThreadingHTTPServer((host, port), Handler)
        self._server.daemon_threads = True
        self.port = int(self._server.server_address[1])
        self._thread = threading.Thread(
            target=self._server.serve_forever, name="metrics-http", daemon=True
        )

    def start(self) -> None:
        self._thread.start()

    def close(self) -> None:
        self._server.shutdown()
        self._server.server_close()


def reference_markdown() -> str:
    """The metrics table of docs/SERVICE.md, from a fresh registry (so it cannot drift)."""
    lines = ["| metric | type | labels | meaning |", "|---|---|---|---|"]
    metrics = Metrics()
    metrics.watch_clocks(lambda: [("vehicle/sensor", -2 * 10**9)])  # a sample shows the label
    for family in metrics.registry.collect():
        labels = sorted({k for s in family.samples for k in s.labels if k != "le"})
        name = {
            "counter": f"{family.name}_total",
            "info": f"{family.name}_info",
        }.get(family.type, family.name)
        lines.append(
            f"| `{name}` | {family.type} | {', '.join(labels) or '-'} | {family.documentation} |"
        )
    return "\n".join(lines)
