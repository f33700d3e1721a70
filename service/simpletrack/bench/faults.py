"""The fleet's ordinary faults, end to end (``simpletrack bench faults``): a real service, real
vehicles through the client library, real signals and a real router process where one is
involved. Each scenario streams a few cars at 10 Hz from a "victim" sensor and a well-behaved
"bystander" sensor, breaks something, and reports what a planner would have seen: frames sent,
tracked, refused, dropped, announced and recovered, how many of the cars kept their track id
across the fault, the bystander's latency and loss, and the service's peak memory.

It measures; it does not judge. The fault tests in tests/faults assert the guarantees.
"""

from __future__ import annotations

import contextlib
import os
import shutil
import signal
import socket
import subprocess
import sys
import tempfile
import threading
import time
from collections.abc import Callable, Iterator
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import zenoh

from simpletrack.bench.stats import status_mb
from simpletrack.client import Box, DetectionPublisher, TrackMessage, TrackSubscriber
from simpletrack.session import ZenohOptions, open_session
from simpletrack.spawn import ROOT, free_port
from simpletrack.wire.codec import Rejection, decode_message, encode_detection_frame
from simpletrack.wire.columns import BoxArrays
from simpletrack.wire.keys import Keys
from simpletrack.wire.models import FrameError
from simpletrack.wire.reasons import DROP_REASONS

CLASSES = ("Car", "Pedestrian", "Cyclist")
RATE_HZ = 10.0
CARS = 6
ROUTER_CODE = """
import sys, time, zenoh
c = zenoh.Config()
c.insert_json5("mode", '"router"')
c.insert_json5("listen/endpoints", '["tcp/127.0.0.1:%s"]' % sys.argv[1])
c.insert_json5("scouting/multicast/enabled", "false")
with zenoh.open(c):
    while True:
        time.sleep(1)
"""


@dataclass
class FaultResult:
    scenario: str
    fault: str
    sent: int = 0
    tracked: int = 0
    refused: int = 0
    dropped: int = 0
    announced: int = 0
    recovered: int = 0
    unanswered: int = 0
    ids_kept: str = "-"
    ids_reused: int = 0
    bystander_sent: int = 0
    bystander_tracked: int = 0
    bystander_p50_ms: float = float("nan")
    bystander_p99_ms: float = float("nan")
    service_peak_mb: float = float("nan")
    notes: list[str] = field(default_factory=list)


def cars_at(t: float) -> list[Box]:
    """CARS cars 6 m apart driving along +x at 5 m/s: car j is the one at y = 6 j."""
    return [Box(10.0 + 5.0 * t, 6.0 * j, 0.8, 0.0, 4.0, 1.8, 1.6, 0.9, "Car") for j in range(CARS)]


class Stream:
    """What one sensor sent and what came back for it."""

    def __init__(self, vehicle: str, sensor: str) -> None:
        self.vehicle, self.sensor = vehicle, sensor
        self.sent: list[tuple[int, int, float]] = []  # (seq, stamp_ns, wall time sent)
        self.tracked: dict[int, tuple[float, dict[int, int]]] = {}  # stamp -> (latency, car -> id)
        self.errors: list[FrameError] = []
        self.lock = threading.Lock()

    def on_tracks(self, msg: TrackMessage) -> None:
        now = time.time_ns()
        ids = {
            round(float(y) / 6.0): int(i)
            for y, i in zip(msg.tracks.center[:, 1], msg.tracks.id, strict=True)
        }
        with self.lock:
            self.tracked[msg.frame.stamp_ns] = ((now - msg.frame.stamp_ns) / 1e6, ids)

    def on_error(self, sample: zenoh.Sample) -> None:
        err = decode_message(sample.payload.to_bytes(), FrameError)
        if not isinstance(err, Rejection):
            with self.lock:
                self.errors.append(err)

    def ids_seen(self, t0: float, t1: float) -> dict[int, set[int]]:
        """Every id each car had among the frames sent in [t0, t1) (wall time)."""
        stamps = {s for _, s, w in self.sent if t0 <= w < t1}
        out: dict[int, set[int]] = {}
        with self.lock:
            for stamp in stamps & set(self.tracked):
                for car, tid in self.tracked[stamp][1].items():
                    out.setdefault(car, set()).add(tid)
        return out

    def ids_between(self, t0: float, t1: float) -> dict[int, int]:
        """Each car's most frequent id among the frames sent in [t0, t1) (wall time)."""
        stamps = {s for _, s, w in self.sent if t0 <= w < t1}
        votes: dict[int, dict[int, int]] = {}
        with self.lock:
            for stamp in stamps & set(self.tracked):
                for car, tid in self.tracked[stamp][1].items():
                    votes.setdefault(car, {}).setdefault(tid, 0)
                    votes[car][tid] += 1
        return {car: max(v, key=v.__getitem__) for car, v in votes.items()}

    def fill(self, r: FaultResult, down: tuple[float, float] | None = None) -> None:
        with self.lock:
            sent_stamps = {s for _, s, _ in self.sent}
            r.sent = len(self.sent)
            r.tracked = len(sent_stamps & set(self.tracked))
            r.dropped = sum(e.reason in DROP_REASONS for e in self.errors)
            r.refused = len(self.errors) - r.dropped
            r.announced = len(self.errors)
            r.unanswered = max(0, r.sent - r.tracked - r.announced)
            if down is not None:
                during = {s for _, s, w in self.sent if down[0] <= w < down[1]}
                r.recovered = len(during & set(self.tracked))

    def latency(self) -> tuple[int, float, float]:
        with self.lock:
            lat = [v[0] for v in self.tracked.values()]
        if not lat:
            return 0, float("nan"), float("nan")
        return len(lat), float(np.percentile(lat, 50)), float(np.percentile(lat, 99))


class Harness:
    """A service (optionally behind a router), and the streams of one scenario."""

    def __init__(
        self,
        work: Path,
        via_router: bool = False,
        *serve_args: str,
        env: dict[str, str] | None = None,
    ) -> None:
        self.work = work
        self.env = {**os.environ, **(env or {})}
        self.state_dir = work / "state"
        self.serve_args = serve_args
        self.router: subprocess.Popen[bytes] | None = None
        self.router_port = free_port() if via_router else 0
        self.service_port = free_port()
        self.service: subprocess.Popen[bytes] | None = None
        self.instance = f"faults-{os.getpid()}"
        self.peak_mb = 0.0

    # --- processes ---------------------------------------------------------------------
    @property
    def endpoint(self) -> str:
        port = self.router_port or self.service_port
        return f"tcp/127.0.0.1:{port}"

    def options(self) -> ZenohOptions:
        if self.router_port:
            return ZenohOptions(mode="client", connect=[self.endpoint], connect_timeout_ms=-1)
        return ZenohOptions(connect=[self.endpoint])

    def start_router(self) -> None:
        self.router = subprocess.Popen(
            [sys.executable, "-c", ROUTER_CODE, str(self.router_port)],
            stdout=subprocess.DEVNULL,
            stderr=subprocess.DEVNULL,
        )
        _wait_port(self.router_port, 20.0)

    def kill_router(self) -> None:
        if self.router is not None:
            self.router.kill()
            self.router.wait()

    def start_service(self) -> None:
        zenoh_args = (
            ["--mode", "client", "--connect", self.endpoint]
            if self.router_port
            else ["--listen", self.endpoint]
        )
        cmd = [
            sys.executable, "-m", "simpletrack.cli.main", "serve", *zenoh_args,
            "--metrics-port", "0", "--instance", self.instance, "--preset", "kitti",
            "--state-dir", str(self.state_dir), "--log-level", "warning", *self.serve_args,
        ]  # fmt: skip
        log = open(self.work / "service.log", "ab")  # noqa: SIM115 - the child writes to it
        self.service = subprocess.Popen(cmd, cwd=ROOT, stdout=log, stderr=log, env=self.env)
        log.close()
        self.wait_ready()

    def wait_ready(self, timeout: float = 30.0) -> None:
        deadline = time.monotonic() + timeout
        with open_session(self.options()) as session:
            while not [r for r in session.get(Keys().status(self.instance), timeout=1.0) if r.ok]:
                if self.service is not None and self.service.poll() is not None:
                    raise RuntimeError(f"the service exited: {self.log_tail()}")
                if time.monotonic() > deadline:
                    raise RuntimeError("the service did not become ready")
                time.sleep(0.05)

    def stop_service(self, sig: int = signal.SIGTERM) -> None:
        if self.service is None:
            return
        self.peak_mb = max(self.peak_mb, _peak_mb(self.service.pid))
        self.service.send_signal(sig)
        try:
            self.service.wait(40)
        except subprocess.TimeoutExpired:
            self.service.kill()
            self.service.wait()

    def log_tail(self) -> str:
        path = self.work / "service.log"
        return path.read_text(errors="replace")[-600:] if path.exists() else ""

    def tracebacks(self) -> int:
        path = self.work / "service.log"
        return path.read_text(errors="replace").count("Traceback") if path.exists() else 0

    def close(self) -> None:
        self.stop_service()
        self.kill_router()


@contextlib.contextmanager
def _listening(session: zenoh.Session, stream: Stream) -> Iterator[None]:
    keys = Keys()
    with (
        TrackSubscriber(
            session, vehicle=stream.vehicle, sensor=stream.sensor, callback=stream.on_tracks
        ),
        session.declare_subscriber(keys.errors(stream.vehicle, stream.sensor), stream.on_error),
    ):
        yield


def _drive(
    pub_of: Callable[[], DetectionPublisher],
    stream: Stream,
    seconds: float,
    stop: threading.Event,
    t_origin: float,
) -> None:
    """Publish at RATE_HZ in real time until ``seconds`` pass or ``stop`` is set; publish
    errors (an outage) are noted as frames sent and not delivered."""
    period = 1.0 / RATE_HZ
    end = time.monotonic() + seconds
    next_at = time.monotonic()
    while not stop.is_set() and time.monotonic() < end:
        now = time.time()
        stamp = time.time_ns()
        with contextlib.suppress(Exception):
            seq = pub_of().publish(cars_at(now - t_origin), stamp_ns=stamp)
            with stream.lock:
                stream.sent.append((seq, stamp, now))
        next_at += period
        time.sleep(max(0.0, next_at - time.monotonic()))


def _wait_port(port: int, timeout: float) -> None:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        with socket.socket() as s:
            s.settimeout(0.2)
            if s.connect_ex(("127.0.0.1", port)) == 0:
                return
        time.sleep(0.05)
    raise RuntimeError(f"nothing listens on 127.0.0.1:{port}")


def _peak_mb(pid: int) -> float:
    mb = status_mb(pid, "VmHWM")
    return float("nan") if mb is None else mb


def _kept(before: dict[int, int], after: dict[int, int]) -> str:
    same = sum(after.get(car) == tid for car, tid in before.items())
    return f"{same}/{len(before)}"


def _reused(before: dict[int, set[int]], after: dict[int, set[int]]) -> int:
    """Ids that name another car after the fault than before it: a planner would mix them."""
    owner = {tid: car for car, ids in before.items() for tid in ids}
    return sum(owner.get(tid, car) != car for car, ids in after.items() for tid in ids)


# --- scenarios ----------------------------------------------------------------------------
Scenario = Callable[[Path], FaultResult]
Pubs = dict[str, DetectionPublisher]
Act = Callable[[Harness, Pubs, zenoh.Session, FaultResult], tuple[float, float] | None]


def _run(
    work: Path,
    name: str,
    fault: str,
    act: Act,
    via_router: bool = False,
    serve_args: tuple[str, ...] = (),
    before_s: float = 3.0,
    after_s: float = 4.0,
    env: dict[str, str] | None = None,
) -> FaultResult:
    """Stream victim and bystander for ``before_s``, run ``act`` (returns the down window in
    wall time, if any), keep streaming ``after_s``; compare ids before and after."""
    h = Harness(work, via_router, *serve_args, env=env)
    result = FaultResult(name, fault)
    victim, bystander = Stream("victim", "lidar"), Stream("bystander", "lidar")
    try:
        if via_router:
            h.start_router()
        h.start_service()
        with (
            open_session(h.options()) as session,
            _listening(session, victim),
            _listening(session, bystander),
        ):
            pubs = {
                s.vehicle: DetectionPublisher(session, s.vehicle, s.sensor, classes=CLASSES)
                for s in (victim, bystander)
            }
            time.sleep(0.5)
            stop = threading.Event()
            t0 = time.time()
            total = before_s + after_s + 30.0
            threads = [
                threading.Thread(
                    target=_drive,
                    args=(lambda s=s: pubs[s.vehicle], s, total, stop, t0),
                    daemon=True,
                )
                for s in (victim, bystander)
            ]
            for t in threads:
                t.start()
            time.sleep(before_s)
            fault_at = time.time()
            down = act(h, pubs, session, result)
            back_at = time.time()
            time.sleep(after_s)
            stop.set()
            for t in threads:
                t.join(5)
            time.sleep(1.0)  # the last answers arrive
            before = victim.ids_between(fault_at - 1.0, fault_at)
            # The first second after the fault is left out: answers to it may still be in flight.
            after = victim.ids_between(back_at + 1.0, back_at + after_s)
            result.ids_kept = _kept(before, after)
            result.ids_reused = _reused(
                victim.ids_seen(0.0, fault_at), victim.ids_seen(back_at, back_at + after_s + 1.0)
            )
            victim.fill(result, down)
            result.bystander_sent = len(bystander.sent)
            result.bystander_tracked, p50, p99 = bystander.latency()
            result.bystander_p50_ms, result.bystander_p99_ms = round(p50, 2), round(p99, 2)
        h.peak_mb = max(h.peak_mb, _peak_mb(h.service.pid) if h.service else 0.0)
        result.service_peak_mb = round(h.peak_mb, 1)
        if h.tracebacks():
            result.notes.append(f"{h.tracebacks()} tracebacks in the service log")
    finally:
        h.close()
    return result


def publisher_restart(work: Path) -> FaultResult:
    def act(h: Harness, pubs: Pubs, session: zenoh.Session, r: FaultResult) -> None:
        pubs["victim"].close()
        pubs["victim"] = DetectionPublisher(session, "victim", "lidar", classes=CLASSES)

    return _run(work, "publisher_restart", "the vehicle restarts its publisher (seq from 0)", act)


def service_crash(work: Path) -> FaultResult:
    def act(h: Harness, pubs: Pubs, session: zenoh.Session, r: FaultResult) -> tuple[float, float]:
        start = time.time()
        h.stop_service(signal.SIGKILL)
        h.start_service()
        return start, time.time()

    return _run(work, "service_crash", "SIGKILL, restart from the state dir", act, via_router=True)


def router_blip(work: Path) -> FaultResult:
    def act(h: Harness, pubs: Pubs, session: zenoh.Session, r: FaultResult) -> tuple[float, float]:
        start = time.time()
        h.kill_router()
        time.sleep(3.0)
        h.start_router()
        time.sleep(2.0)  # clients reconnect by themselves
        return start, time.time()

    return _run(work, "router_blip", "the router is down for 3 s", act, via_router=True)


def heavy_frame(work: Path) -> FaultResult:
    def act(h: Harness, pubs: Pubs, session: zenoh.Session, r: FaultResult) -> None:
        rng = np.random.default_rng(0)
        for k in range(2):
            n = 3000
            boxes = BoxArrays(
                classes=CLASSES,
                class_index=np.zeros(n, np.int32),
                center=np.column_stack([rng.uniform(-100, 100, (n, 2)), np.full(n, 0.8)]).astype(
                    np.float32
                ),
                size=np.tile(np.array([4.0, 1.8, 1.6], np.float32), (n, 1)),
                yaw=rng.uniform(-3, 3, n).astype(np.float32),
                score=rng.uniform(0.1, 1.0, n),
            )
            payload = encode_detection_frame(
                vehicle="heavy",
                sensor="lidar",
                seq=k,
                stamp_ns=time.time_ns(),
                frame_id="lidar",
                boxes=boxes,
            )
            session.put(Keys().detections("heavy", "lidar"), payload)
            time.sleep(0.1)

    return _run(work, "heavy_frame", "another sensor sends two 3,000-box frames", act)


def garbage_flood(work: Path) -> FaultResult:
    def act(h: Harness, pubs: Pubs, session: zenoh.Session, r: FaultResult) -> None:
        key = Keys().detections("noisy", "lidar")
        with session.declare_publisher(
            key, congestion_control=zenoh.CongestionControl.BLOCK
        ) as pub:
            end = time.monotonic() + 2.0
            while time.monotonic() < end:
                pub.put(os.urandom(200))

    return _run(work, "garbage_flood", "another sensor floods garbage for 2 s", act)


def query_flood(work: Path) -> FaultResult:
    def act(h: Harness, pubs: Pubs, session: zenoh.Session, r: FaultResult) -> None:
        end = time.monotonic() + 2.0
        selector = Keys().snapshot()
        while time.monotonic() < end:
            for _ in range(50):
                session.get(selector, timeout=1.0)  # replies are never read: a flood

    return _run(work, "query_flood", "wildcard snapshot queries for 2 s", act)


def slot_exhaustion(work: Path) -> FaultResult:
    def act(h: Harness, pubs: Pubs, session: zenoh.Session, r: FaultResult) -> None:
        for i in range(40):  # one frame each on distinct keys: every slot taken
            payload = encode_detection_frame(
                vehicle=f"squat{i:02d}", sensor="lidar", seq=0, stamp_ns=time.time_ns(),
                frame_id="lidar", boxes=_boxes(np.zeros((1, 3))),
            )  # fmt: skip
            session.put(Keys().detections(f"squat{i:02d}", "lidar"), payload)
        newcomer = Stream("newcomer", "lidar")
        stop = threading.Event()
        with _listening(session, newcomer):
            pub = DetectionPublisher(session, "newcomer", "lidar", classes=CLASSES)
            started = time.time()
            _drive(lambda: pub, newcomer, 8.0, stop, started)
            time.sleep(0.5)
            pub.close()
        first = min((w for _, s, w in newcomer.sent if s in newcomer.tracked), default=None)
        wait = "never" if first is None else f"{first - started:.1f} s"
        r.notes.append(
            f"a new sensor at capacity (max_sensors 10): {len(newcomer.tracked)} of "
            f"{len(newcomer.sent)} frames tracked, first after {wait}, "
            f"{len(newcomer.errors)} refused"
        )

    return _run(work, "slot_exhaustion", "40 one-frame sensors fill max_sensors=10", act,
                env={"SIMPLETRACK_MAX_SENSORS": "10"}, after_s=3.0)  # fmt: skip


def absurd_values(work: Path) -> FaultResult:
    def act(h: Harness, pubs: Pubs, session: zenoh.Session, r: FaultResult) -> None:
        for value in (3.4e38, 1e12, -1e9):
            pubs["victim"].publish([Box(value, 0.0, 0.8, 0.0, 4.0, 1.8, 1.6, 0.9, "Car")])
            time.sleep(0.1)

    return _run(work, "absurd_values", "three frames with boxes at 3.4e38, 1e12, -1e9 m", act)


def newline_key(work: Path) -> FaultResult:
    def act(h: Harness, pubs: Pubs, session: zenoh.Session, r: FaultResult) -> None:
        payload = encode_detection_frame(
            vehicle="victim", sensor="lidar", seq=0, stamp_ns=time.time_ns(),
            frame_id="lidar", boxes=_boxes(np.zeros((1, 3))),
        )  # fmt: skip
        for _ in range(20):
            try:
                session.put("fleet/bad\n/lidar/detections", payload)
            except Exception as exc:  # Zenoh may refuse the key itself
                r.notes.append(f"Zenoh refused the key: {exc}"[:120])
                return
            time.sleep(0.05)

    return _run(work, "newline_key", "20 frames on a key chunk ending in a newline", act)


def damaged_snapshot(work: Path) -> FaultResult:
    def act(h: Harness, pubs: Pubs, session: zenoh.Session, r: FaultResult) -> tuple[float, float]:
        start = time.time()
        h.stop_service(signal.SIGTERM)
        for path in (h.state_dir / "victim").glob("lidar*"):
            if path.suffix != ".ids":
                path.write_bytes(path.read_bytes()[:20])  # truncated
        h.start_service()
        return start, time.time()

    return _run(work, "damaged_snapshot", "SIGTERM, the snapshot truncated, restart", act,
                via_router=True)  # fmt: skip


def _boxes(centers: np.ndarray[Any, Any]) -> BoxArrays:
    n = len(centers)
    return BoxArrays(
        classes=CLASSES,
        class_index=np.zeros(n, np.int32),
        center=np.asarray(centers, np.float32),
        size=np.tile(np.array([4.0, 1.8, 1.6], np.float32), (n, 1)),
        yaw=np.zeros(n, np.float32),
        score=np.full(n, 0.9),
    )


SCENARIOS: dict[str, Scenario] = {
    f.__name__: f
    for f in (
        publisher_restart,
        service_crash,
        router_blip,
        heavy_frame,
        garbage_flood,
        query_flood,
        slot_exhaustion,
        absurd_values,
        newline_key,
        damaged_snapshot,
    )
}


def run_faults(names: list[str] | None = None) -> list[FaultResult]:
    out = []
    for name in names or list(SCENARIOS):
        work = Path(tempfile.mkdtemp(prefix=f"faults-{name}-"))
        try:
            out.append(SCENARIOS[name](work))
        except Exception as exc:  # a scenario that cannot run is a finding, not a crash
            out.append(FaultResult(name, "-", notes=[f"{type(exc).__name__}: {exc}"[:300]]))
        finally:
            shutil.rmtree(work, ignore_errors=True)
    return out


def format_results(results: list[FaultResult]) -> str:
    head = (
        f"{'scenario':<18} {'sent':>5} {'tracked':>7} {'refused':>7} {'dropped':>7} "
        f"{'announced':>9} {'recovered':>9} {'unanswered':>10} {'ids kept':>8} {'reused':>6} "
        f"{'bystander p50/p99 ms':>21} {'loss':>5} {'peak MB':>8}"
    )
    rows = [head]
    for r in results:
        loss = r.bystander_sent - r.bystander_tracked
        rows.append(
            f"{r.scenario:<18} {r.sent:>5} {r.tracked:>7} {r.refused:>7} {r.dropped:>7} "
            f"{r.announced:>9} {r.recovered:>9} {r.unanswered:>10} {r.ids_kept:>8} {r.ids_reused:>6} "
            f"{f'{r.bystander_p50_ms:.1f} / {r.bystander_p99_ms:.1f}':>21} {loss:>5} "
            f"{r.service_peak_mb:>8.0f}"
        )
        rows.extend(f"  {r.scenario}: {note}" for note in r.notes)
    return "\n".join(rows)


def as_dicts(results: list[FaultResult]) -> list[dict[str, Any]]:
    return [asdict(r) for r in results]
