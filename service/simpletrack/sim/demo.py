"""The live demo: the tracking service and a simulated fleet on one machine, no router and no
data files, with the planner-side view scored against the simulator's ground truth.

Every vehicle has a 360-degree lidar at 10 Hz and a front camera at 15 Hz that sees farther,
noisier and later (``fusion_sensors``); the service fuses them into one track list per
vehicle and also publishes each sensor's own tracks, so that both are scored on the same
frames against the vehicle's truth (``vehicle_score``).

Frames are paced in real time: a frame of the simulator's tick k is stamped ``start + k x dt``
(its capture time) and sent that long after the start plus the sensor's latency
(``SensorSpec.latency_s``), so the latency (stamp to arrival at the planner) includes the
sensor's and any lag of the demo itself. Tracks come back in the world frame (the frames
carry the sensor pose).
"""

from __future__ import annotations

import heapq
import logging
import math
import os
import signal
import subprocess
import sys
import tempfile
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from enum import StrEnum
from pathlib import Path
from typing import Any

import numpy as np

from simpletrack.client.jsonl import JsonlWriter, message_to_json
from simpletrack.client.mailbox import Mailbox
from simpletrack.client.publisher import DetectionPublisher
from simpletrack.client.subscriber import (
    TrackMessage,
    TrackSubscriber,
    VehicleTrackMessage,
    VehicleTrackSubscriber,
)
from simpletrack.core import jit, solvers
from simpletrack.datasets.recording import truth_to_json
from simpletrack.mcap.format import LEAVES
from simpletrack.mcap.ros2 import Ros2Bag
from simpletrack.mcap.writer import McapRecorder, subscribe
from simpletrack.ros2.recording import AutowareMessages
from simpletrack.session import ZenohOptions, open_session
from simpletrack.sim.demo_fusion import VehicleCollector
from simpletrack.sim.demo_stats import FleetStats
from simpletrack.sim.demo_tracker import DEMO_PRESET as DEMO_PRESET
from simpletrack.sim.demo_tracker import (
    demo_fusion,
    demo_tracker_config,
    write_class_overrides,
    write_service_config,
)
from simpletrack.sim.fusion_sensors import fusion_sensors
from simpletrack.sim.simulator import FleetSimulator, SensorFrame, SimConfig, vehicle_id
from simpletrack.sim.vehicle_score import FleetScores
from simpletrack.spawn import free_port
from simpletrack.view import Fov, PortInUse, ViewServer, serve_view
from simpletrack.wire import BoxArrays, FrameError, WireTrackState
from simpletrack.wire.keys import VEHICLE_STREAM


class ServiceMode(StrEnum):
    # `simpletrack serve` as a child process: its own GIL, so latencies are the service's.
    SUBPROCESS = "subprocess"
    # The service's threads in this process: starts faster, but shares the GIL with the
    # simulator and the view (measured p99 latency 114 ms against 18 ms as a subprocess).
    INPROCESS = "inprocess"
    EXTERNAL = "external"  # a service that is already running (reach it with --connect)


@dataclass(frozen=True)
class DemoOptions:
    sim: SimConfig = field(default_factory=lambda: SimConfig(sensors=fusion_sensors()))
    duration: float | None = None  # None: until stopped
    service: ServiceMode = ServiceMode.SUBPROCESS
    listen: str | None = None  # where an in-process/subprocess service listens
    client: ZenohOptions | None = None  # how the demo's clients connect (external service)
    prefix: str = "fleet"
    inject_errors: float = 0.0  # share of frames sent broken on purpose (rejected by the service)
    record: Path | None = None
    metrics_port: int = 0
    service_log: Path | None = None
    drain_s: float = 2.0  # after the last frame, wait this long for its tracks
    view_port: int | None = 8090  # the browser view's port (0: any free one; None: no view)
    mcap: Path | None = None  # record the fleet's detections, tracks and errors here
    ros2: Path | None = None  # with mcap: a ROS 2 bag of the same frames (Autoware messages)


@dataclass
class DemoResult:
    stats: FleetStats
    elapsed: float
    frames: int  # simulator ticks (frames per sensor when every sensor runs at the fleet rate)
    endpoint: str
    service: ServiceMode
    stopped_by: str
    unanswered: int = 0
    view_url: str | None = None  # the live view in the browser, when it runs


def free_endpoint() -> str:
    return f"tcp/127.0.0.1:{free_port()}"


class _Service:
    """The service under the demo, whichever way it runs."""

    def __init__(self, options: DemoOptions, endpoint: str) -> None:
        self.options = options
        self.endpoint = endpoint
        self._inproc: Any = None
        self._proc: subprocess.Popen[bytes] | None = None
        self._log_file: Any = None
        self._temp_log: Path | None = None  # removed after a clean stop
        self._overrides: Path | None = None  # the demo's tracker settings, removed at stop
        self._config: Path | None = None  # its fusion settings, removed at stop

    def start(self) -> None:
        o = self.options
        if o.service is not ServiceMode.EXTERNAL:
            self._overrides = write_class_overrides()
            self._config = write_service_config(o.sim)
        if o.service is ServiceMode.INPROCESS:
            from simpletrack.server.app import Service
            from simpletrack.server.settings import load_settings

            _quiet_service_logs(o.service_log)
            settings = load_settings(
                None,
                {
                    "preset": DEMO_PRESET,
                    "class_overrides": self._overrides,
                    "prefix": o.prefix,
                    "instance": "demo",
                    "zenoh": {"mode": "peer", "listen": [self.endpoint], "connect": []},
                    "metrics_port": o.metrics_port,
                    "state_dir": None,
                    "fusion": demo_fusion(o.sim),
                },
            )
            self._inproc = Service(settings)
            self._inproc.start()
        elif o.service is ServiceMode.SUBPROCESS:
            if o.service_log is not None:
                log_path = o.service_log
            else:
                fd, name = tempfile.mkstemp(prefix="simpletrack-demo-", suffix=".log")
                os.close(fd)
                log_path = Path(name)
                self._temp_log = log_path
            self._log_file = log_path.open("wb")
            cmd = [
                sys.executable, "-c", "import sys; from simpletrack.cli.main import main; sys.exit(main())",
                "serve",
                "--listen", self.endpoint, "--preset", DEMO_PRESET, "--prefix", o.prefix,
                "--class-overrides", str(self._overrides), "--config", str(self._config),
                "--instance", "demo", "--metrics-port", str(o.metrics_port),
                "--log-level", "warning",
            ]  # fmt: skip
            # The child imports this very package, wherever it was imported from here.
            env = {**os.environ, "PYTHONPATH": os.pathsep.join(p for p in sys.path if p)}
            self._proc = subprocess.Popen(
                cmd,
                stdout=self._log_file,
                stderr=subprocess.STDOUT,
                start_new_session=True,
                env=env,
            )
            self.log_path = log_path

    def check_alive(self) -> None:
        if self._proc is not None and self._proc.poll() is not None:
            raise RuntimeError(
                f"the service exited with code {self._proc.returncode}; see {self.log_path}"
            )

    def stop(self) -> None:
        if self._inproc is not None:
            self._inproc.shutdown()
            self._inproc = None
        clean = True
        if self._proc is not None:
            if self._proc.poll() is None:
                self._proc.send_signal(signal.SIGTERM)
                try:
                    self._proc.wait(timeout=15)
                except subprocess.TimeoutExpired:
                    self._proc.kill()
                    self._proc.wait()
            clean = self._proc.returncode == 0
            self._proc = None
        if self._log_file is not None:
            self._log_file.close()
            self._log_file = None
        if clean and self._temp_log is not None:
            self._temp_log.unlink(missing_ok=True)
        for path in (self._overrides, self._config):
            if path is not None:
                path.unlink(missing_ok=True)
        self._overrides = self._config = None


def _quiet_service_logs(path: Path | None) -> None:
    """The in-process service logs to a file when asked; otherwise only errors, to stderr."""
    root = logging.getLogger("simpletrack")
    root.propagate = False
    if path is not None:
        from simpletrack.server import logs
        from simpletrack.server.settings import LogFormat, LogLevel

        logs.configure(LogFormat.JSON, LogLevel.INFO)
        handler: logging.Handler = logging.FileHandler(path)
        handler.setFormatter(root.handlers[0].formatter)
        root.handlers[:] = [handler]
    else:
        handler = logging.StreamHandler(sys.stderr)
        handler.setLevel(logging.ERROR)
        root.handlers[:] = [handler]
        root.setLevel(logging.ERROR)


def broken_frame(classes: tuple[str, ...]) -> BoxArrays:
    """A frame the service must refuse (a NaN centre): shows the errors path."""
    return BoxArrays(
        classes=classes,
        class_index=np.zeros(1, np.int32),
        center=np.array([[np.nan, 0.0, 0.0]], np.float32),
        size=np.ones((1, 3), np.float32),
        yaw=np.zeros(1, np.float32),
        score=np.ones(1, np.float32),
    )


class FleetDemo:
    """Runs the demo; ``on_tick(result_so_far)`` is called about 4 times a second."""

    def __init__(self, options: DemoOptions) -> None:
        self.options = options
        sensors = tuple(s.name for s in options.sim.sensors)
        self.stats = FleetStats(FleetScores(sensors))
        self.stop_event = threading.Event()
        self._errors: Mailbox[FrameError] = Mailbox(100_000)
        self.tracker_config = demo_tracker_config()
        self.class_names = self.tracker_config.class_names
        self.collector = VehicleCollector(self.stats.scores, self.tracker_config, sensors)
        options.sim.check_tracker_config(self.tracker_config)
        self._rng = np.random.default_rng(options.sim.seed + 1)
        self._tracks_out: JsonlWriter | None = None
        self._truth_out: JsonlWriter | None = None

    def request_stop(self, *_: object) -> None:
        self.stop_event.set()

    def run(self, on_tick: Callable[[DemoResult], None] | None = None) -> DemoResult:
        o = self.options
        endpoint = o.listen or free_endpoint()
        service = _Service(o, endpoint)
        client = o.client or ZenohOptions(connect=[endpoint])
        # The fleet's session listens and the observers' (view, recorder) connects to it:
        # peers do not pass on each other's samples, so they hear detections straight from
        # the publishers.
        observing = o.view_port is not None or o.mcap is not None
        fleet_listen = free_endpoint() if observing and o.client is None else None
        if fleet_listen is not None:
            client = ZenohOptions(connect=[endpoint], listen=[fleet_listen])
        if o.service is ServiceMode.EXTERNAL:
            endpoint = ", ".join(client.connect) or "(scouting)"
        if o.record is not None:
            self._tracks_out = JsonlWriter(o.record / "tracks.jsonl")
            self._truth_out = JsonlWriter(o.record / "truth.jsonl")
        result = DemoResult(self.stats, 0.0, 0, endpoint, o.service, "duration")
        session = None
        view: ViewServer | None = None
        recorder: McapRecorder | None = None
        recording: list[Any] = []
        view_session = None
        try:
            service.start()
            # The planner-side scoring runs the core's NMS and IoU (compiled kernels) and
            # scipy's assignment: loaded now, while the service starts, not on the first
            # frame's tracks (that stalled the paced loop ~0.5 s and made the latency tail).
            solvers.preload()
            jit.preload()
            session = open_session(client)
            sim = FleetSimulator(o.sim)
            sub = TrackSubscriber(session, prefix=o.prefix, buffer=100_000)
            vsub = VehicleTrackSubscriber(session, prefix=o.prefix, buffer=100_000)
            pubs = {
                stream: DetectionPublisher(
                    session,
                    *stream,
                    classes=self.class_names,
                    prefix=o.prefix,
                    frame_id=stream[1],
                    on_error=self._errors.put,
                )
                for stream in sim.streams
            }
            for stream in sim.streams:
                self.stats.stream(*stream)
            for v in sorted({v for v, _ in sim.streams}):
                self.stats.stream(v, VEHICLE_STREAM)
            first = next(iter(pubs.values()))
            deadline = time.monotonic() + 20.0
            while not first.wait_for_service(0.2):
                service.check_alive()
                if self.stop_event.is_set():
                    result.stopped_by = "interrupted"
                    return result
                if time.monotonic() > deadline:
                    raise RuntimeError(f"no tracking service answered on {endpoint}")
            if o.service is ServiceMode.EXTERNAL:
                self._check_external(session)
            if observing:
                # Only now: an observer's detections subscriber would pass for the service in
                # wait_for_service, and the first frames would go before it listens.
                view_options = o.client or ZenohOptions(
                    connect=[endpoint, *([fleet_listen] if fleet_listen else [])]
                )
                view_session = open_session(view_options)
                if o.view_port is not None:
                    view = self._start_view(view_session, result)
                if o.mcap is not None:
                    bag = None
                    if o.ros2 is not None:
                        bag = Ros2Bag(o.ros2, o.prefix, AutowareMessages())
                    recorder = McapRecorder(o.mcap, o.prefix, ros2=bag)
                    recording = subscribe(
                        view_session, o.prefix, [("*", "*")], list(LEAVES), recorder
                    )
            subs = (sub, vsub)
            result.stopped_by = self._loop(sim, pubs, subs, service, result, on_tick)
            self._drain(subs, o.drain_s)
            result.unanswered = self._unanswered()
            self.collector.flush()
            sub.close()
            vsub.close()
        finally:
            if view is not None:
                view.close()
            for rec_sub in recording:
                rec_sub.undeclare()
            if recorder is not None:
                recorder.close()
            if view_session is not None:
                view_session.close()  # type: ignore[no-untyped-call]
            if session is not None:
                session.close()  # type: ignore[no-untyped-call]
            service.stop()
            for w in (self._tracks_out, self._truth_out):
                if w is not None:
                    w.close()
        return result

    def _start_view(self, session: Any, result: DemoResult) -> ViewServer:
        """The browser view on the observers' Zenoh session, a planner's like any other:
        tracks and detections of the whole fleet, each sensor's field of view from the
        simulator. A taken port is not worth failing the demo for: any free port then, said
        in the URL."""
        port = self.options.view_port or 0
        fov = {s.name: Fov(s.fov_deg, s.max_range) for s in self.options.sim.sensors}
        prefix = self.options.prefix
        try:
            view = serve_view(session, prefix, port=port, detections=True, fov=fov)
        except PortInUse:
            view = serve_view(session, prefix, port=0, detections=True, fov=fov)
        first = f"{vehicle_id(0)}/{VEHICLE_STREAM}"  # the fused vehicle: what planners get
        result.view_url = f"{view.url}?sensor={first}"
        return view

    def _check_external(self, session: Any) -> None:
        """A running service must track the simulator's classes, or every frame is refused."""
        from simpletrack.wire import Rejection, ServiceStatus, decode_message
        from simpletrack.wire.keys import Keys

        statuses: list[ServiceStatus] = []
        deadline = time.monotonic() + 3.0
        # The queryable's route may reach us a little after the subscriber's: ask again.
        while not statuses and time.monotonic() < deadline:
            for reply in session.get(Keys(self.options.prefix).status(), timeout=1.0):
                if reply.ok is not None:
                    status = decode_message(reply.ok.payload.to_bytes(), ServiceStatus)
                    if not isinstance(status, Rejection):
                        statuses.append(status)
            if not statuses:
                time.sleep(0.1)
        for status in statuses:
            missing = [c for c in self.class_names if c not in status.classes]
            if missing:
                raise RuntimeError(
                    f"service {status.instance} tracks {', '.join(status.classes)} (preset "
                    f"{status.preset}); the demo's fleet sends {', '.join(self.class_names)}: "
                    f"start it with --preset {DEMO_PRESET}"
                )

    # ------------------------------------------------------------------ the loop
    def _loop(
        self,
        sim: FleetSimulator,
        pubs: dict[tuple[str, str], DetectionPublisher],
        subs: tuple[TrackSubscriber, VehicleTrackSubscriber],
        service: _Service,
        result: DemoResult,
        on_tick: Callable[[DemoResult], None] | None,
    ) -> str:
        o = self.options
        dt = sim.dt
        # By send time: a sensor's latency can send a frame after later-stamped ones of other
        # sensors (never of its own stream); the counter keeps equal times in step() order.
        pending: list[tuple[float, int, int, SensorFrame]] = []
        order = 0
        last_send: dict[tuple[str, str], float] = {}  # a stream's frames go in order
        t0 = time.monotonic()
        t0_ns = time.time_ns()
        next_view = t0
        k = 0
        while True:
            now = time.monotonic()
            result.elapsed = now - t0
            if self.stop_event.is_set():
                return "interrupted"
            if o.duration is not None and now - t0 >= o.duration:
                return "duration"
            if now >= t0 + k * dt:
                by_vehicle: dict[str, list[SensorFrame]] = {}
                for f in sim.step():
                    # Stamped at its capture: the vehicle's tracker orders its sensors by it.
                    stamp_ns = t0_ns + round(f.stamp * 1e9)
                    stream = (f.vehicle, f.sensor)
                    send = max(t0 + f.stamp + f.latency_s, last_send.get(stream, -math.inf))
                    last_send[stream] = send
                    heapq.heappush(pending, (send, order, stamp_ns, f))
                    order += 1
                    by_vehicle.setdefault(f.vehicle, []).append(f)
                for frames in by_vehicle.values():
                    self.collector.expect(frames, t0_ns + round(frames[0].stamp * 1e9))
                k += 1
                result.frames = k
            while pending and pending[0][0] <= now:
                _, _, stamp_ns, f = heapq.heappop(pending)
                self._publish(f, pubs[(f.vehicle, f.sensor)], stamp_ns)
            due = min(t0 + k * dt, pending[0][0] if pending else math.inf)
            self._consume(subs, timeout=min(due - time.monotonic(), 0.05))
            if now >= next_view:
                service.check_alive()
                if on_tick is not None:
                    on_tick(result)
                next_view = now + 0.25

    def _publish(self, f: SensorFrame, pub: DetectionPublisher, stamp_ns: int) -> None:
        stream = (f.vehicle, f.sensor)
        if self.options.inject_errors and self._rng.random() < self.options.inject_errors:
            pub.publish_arrays(
                broken_frame(self.class_names), stamp_ns=stamp_ns, pose=f.pose, seq=f.seq
            )
        else:
            pub.publish(f.detections, stamp_ns=stamp_ns, pose=f.pose, seq=f.seq)
        if self._truth_out is not None:
            self._truth_out.write(
                truth_to_json(
                    *stream,
                    f.seq,
                    stamp_ns,
                    f.truth_ids,
                    f.truth,
                    self.class_names,
                    f.truth_ignore,
                )
            )
        self.stats.stream(*stream).sent += 1

    def _consume(
        self, subs: tuple[TrackSubscriber, VehicleTrackSubscriber], timeout: float
    ) -> None:
        sub, vsub = subs
        msg = sub.recv(timeout=max(timeout, 0.0))
        while msg is not None:
            self._score(msg)
            msg = sub.try_recv()
        vmsg = vsub.try_recv()
        while vmsg is not None:
            self._score_vehicle(vmsg)
            vmsg = vsub.try_recv()
        err = self._errors.get_nowait()
        while err is not None:
            st = self.stats.stream(err.vehicle, err.sensor)
            st.rejected[err.reason.value] += 1
            self.collector.refused(err)
            err = self._errors.get_nowait()

    def _score(self, msg: TrackMessage) -> None:
        st = self.stats.stream(msg.vehicle, msg.sensor)
        ids = msg.tracks.id.astype(np.int64)
        confirmed = int((msg.tracks.state != WireTrackState.TENTATIVE).sum())
        st.on_tracks(time.monotonic(), msg.latency_s, ids, confirmed)
        self.stats.latency.add(msg.latency_s)
        self.collector.sensor_tracks(msg, self.class_names)
        if self._tracks_out is not None:
            self._tracks_out.write(message_to_json(msg.frame, msg.tracks))

    def _score_vehicle(self, msg: VehicleTrackMessage) -> None:
        st = self.stats.stream(msg.vehicle, VEHICLE_STREAM)
        ids = msg.tracks.id.astype(np.int64)
        confirmed = int((msg.tracks.state != WireTrackState.TENTATIVE).sum())
        st.on_tracks(time.monotonic(), msg.latency_s, ids, confirmed)
        self.stats.fused_latency.add(msg.latency_s)
        self.collector.vehicle_tracks(msg, self.class_names)

    def _unanswered(self) -> int:
        return max(0, self.stats.sent - self.stats.tracked - sum(self.stats.rejected.values()))

    def _drain(self, subs: tuple[TrackSubscriber, VehicleTrackSubscriber], seconds: float) -> None:
        deadline = time.monotonic() + seconds
        while time.monotonic() < deadline and self._unanswered() > 0:
            self._consume(subs, timeout=0.05)
        self._consume(subs, timeout=0.0)
