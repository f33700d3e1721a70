"""A neighbour's flood never delays a new sensor (the issue: two valid 3000-box frames of a
fresh sensor, sent right after a 5 s garbage flood on another vehicle's key, were answered
after 7-8 s or never; 0.13 s on a quiet service).

One service with its defaults (but ``sensor_idle_s``). A calm sensor streams at 10 Hz
throughout. A flooder process (a vehicle of its own: its own Zenoh session) puts garbage on
its key as fast as it can for 5 s, then stays connected; the service still has the flood's
backlog to read from that link. Right after it:

- a new sensor (its own session, on the flood's worker) sends two 3000-box frames;
- a sensor whose state was evicted while it was silent (``sensor_idle_s`` 1 s; on the other
  worker) comes back with two 3000-box frames;

then, during a flood of snapshot and status queries from another process, a third new
sensor sends two. Each frame must be answered within ANSWER_S of its put; the calm sensor
loses nothing and keeps its latency (``calm_figures`` says which bounds, and why).
Without the pause of server/gil.py (3 runs on this 2-core machine) the new sensor's second
frame was answered after 0.78-1.6 s, the returning sensor's after up to 1.1 s, and the calm
sensor's worst frame took 0.74-1.6 s: the flood's backlog kept the interpreter lock from the
worker tracking them. With it: 0.11 s, 0.19 s and 0.07 s at most (10 runs).
"""

from __future__ import annotations

import signal
import subprocess
import sys
import textwrap
import threading
import time
from pathlib import Path

import numpy as np
import pytest
import zenoh

from simpletrack.server.intake import worker_index
from simpletrack.session import open_session
from simpletrack.wire import (
    BoxArrays,
    FrameError,
    Rejection,
    decode_message,
    decode_track_frame,
    encode_detection_frame,
)
from simpletrack.wire.keys import Keys
from tests.service_helpers import ROOT, ServiceProcess, metric, moving_cars, start_service, wait_for

pytestmark = pytest.mark.zenoh

FLOOD_S = 5.0
ANSWER_S = 1.0  # the bound for a new sensor's first frames
BOXES = 3000
KEYS = Keys("fleet")
INSTANCE = "svc-flood"
FLOODED = ("vflood", "noisy")
NEW = ("vnew", "lidar")  # a fresh sensor on the flood's worker: its lane joins the rotation
EVICTED = ("vback", "lidar")  # on the other worker: heard, evicted while silent, back
QUERIED = ("vquery", "lidar")  # a fresh sensor while the queries flood
CALM = ("vcalm", "lidar")

# A vehicle of its own that misbehaves: garbage on its key, or queries on the service's
# queryables, as fast as one process can, for ``seconds``; then it stays connected (what it
# sent and the service has not read yet is still on its link) until its stdin closes.
FLOODER = textwrap.dedent(
    """
    import sys, time
    from simpletrack.session import open_session
    endpoint, seconds, what, *targets = sys.argv[1:]
    session = open_session(mode="peer", connect=[endpoint])
    end, n = time.monotonic() + float(seconds), 0
    if what == "garbage":
        pub = session.declare_publisher(targets[0])
        junk = [bytes([0xC1]) * k for k in range(1, 64)]
        print("flooding", flush=True)
        while time.monotonic() < end:
            for j in junk:
                pub.put(j)
            n += len(junk)
    else:
        print("flooding", flush=True)
        while time.monotonic() < end:
            for selector in targets:
                session.get(selector, lambda reply: None)
            n += len(targets)
    print("done", n, flush=True)
    sys.stdin.read()
    """
)


def flooder(endpoint: str, what: str, *targets: str) -> subprocess.Popen[str]:
    proc = subprocess.Popen(
        [sys.executable, "-c", FLOODER, endpoint, str(FLOOD_S), what, *targets],
        cwd=ROOT,
        stdin=subprocess.PIPE,
        stdout=subprocess.PIPE,
        text=True,
    )
    assert proc.stdout is not None and proc.stdout.readline() == "flooding\n"
    return proc


def stop(proc: subprocess.Popen[str]) -> None:
    proc.send_signal(signal.SIGKILL)
    proc.wait()


def grid(k: int, n: int = BOXES) -> BoxArrays:
    """Frame k of n cars on a 60-wide grid 10 m apart, all driving +x at 10 m/s (10 Hz)."""
    i = np.arange(n)
    center = np.stack([(i % 60) * 10.0 + k, (i // 60) * 10.0, np.full(n, 0.8)], axis=1)
    return BoxArrays(
        classes=("Car",),
        class_index=np.zeros(n, np.int32),
        center=center.astype(np.float32),
        size=np.tile(np.float32([4.0, 1.8, 1.6]), (n, 1)),
        yaw=np.zeros(n, np.float32),
        score=np.full(n, 0.9, np.float32),
    )


class Sensor:
    """One sensor of a vehicle with its own Zenoh session: its detections publisher (BLOCK, as
    the client library's) and the service's answers on its own tracks and errors keys, with
    when each frame was put and answered (perf_counter)."""

    def __init__(self, endpoint: str, names: tuple[str, str]) -> None:
        self.vehicle, self.sensor = names
        self.session = open_session(mode="peer", connect=[endpoint])
        self.sent: dict[int, float] = {}
        self.answered: dict[int, float] = {}
        self.errors: list[FrameError] = []
        self.lock = threading.Lock()
        self._subs = [
            self.session.declare_subscriber(KEYS.tracks(*names), self._on_tracks),
            self.session.declare_subscriber(KEYS.errors(*names), self._on_errors),
        ]
        key = KEYS.detections(*names)
        self.pub = self.session.declare_publisher(
            key, congestion_control=zenoh.CongestionControl.BLOCK
        )
        wait_for(lambda: self.pub.matching_status.matching, 10, f"the service on {key}")

    def _on_tracks(self, sample: zenoh.Sample) -> None:
        t = time.perf_counter()
        out = decode_track_frame(sample.payload.to_bytes())
        assert not isinstance(out, Rejection), out
        with self.lock:
            self.answered[out[0].seq] = t

    def _on_errors(self, sample: zenoh.Sample) -> None:
        err = decode_message(sample.payload.to_bytes(), FrameError)
        assert not isinstance(err, Rejection), err
        with self.lock:
            self.errors.append(err)

    def frame(self, seq: int, boxes: BoxArrays, stamp_ns: int) -> bytes:
        return encode_detection_frame(
            vehicle=self.vehicle, sensor=self.sensor, seq=seq, stamp_ns=stamp_ns,
            frame_id="lidar", boxes=boxes,
        )  # fmt: skip

    def put(self, seq: int, payload: bytes) -> None:
        self.sent[seq] = time.perf_counter()
        self.pub.put(payload)

    def answer_times(self, seqs: list[int], timeout: float = 20.0) -> list[float]:
        """Seconds from each frame's put to its tracks (waits for them all)."""
        wait_for(lambda: all(s in self.answered for s in seqs), timeout, f"{self.vehicle}")
        with self.lock:
            return [self.answered[s] - self.sent[s] for s in seqs]

    def close(self) -> None:
        self.session.close()  # type: ignore[no-untyped-call]


def two_heavy_frames(sensor: Sensor, first: int) -> list[float]:
    """Put two 3000-box frames of ``sensor`` (encoded beforehand) back to back; the seconds
    to each one's answer."""
    now = time.time_ns()
    payloads = [sensor.frame(first + k, grid(k), now + (k - 1) * 100_000_000) for k in (0, 1)]
    for k, payload in enumerate(payloads):
        sensor.put(first + k, payload)
    return sensor.answer_times([first, first + 1])


class Calm(threading.Thread):
    """The calm sensor: a frame of 8 cars every 100 ms until stopped."""

    def __init__(self, sensor: Sensor) -> None:
        super().__init__(daemon=True)
        self.s, self.stopped, self.n = sensor, threading.Event(), 0

    def run(self) -> None:
        next_at = time.perf_counter()
        while not self.stopped.is_set():
            self.s.put(self.n, self.s.frame(self.n, moving_cars(self.n, n=8), time.time_ns()))
            self.n += 1
            next_at += 0.1
            time.sleep(max(0.0, next_at - time.perf_counter()))


def calm_figures(calm: Calm, phases: list[int]) -> dict[str, float]:
    """The calm sensor's latency (put to tracks, seconds) before the floods (its frames up
    to ``phases[0]``), through the garbage flood and the frames after it (up to
    ``phases[1]``), and through the queries' flood. The bounds the test holds them to:

    - garbage flood: median at most twice the one before + 20 ms (the flood takes a core and
      much of the interpreter lock on 2 shared cores, as in the neighbour test), no frame
      over 0.5 s (one can wait behind a 3000-box frame of its worker, ~0.1 s; without the
      fix the flood's backlog held them 0.74-1.6 s);
    - queries' flood: no frame over ANSWER_S. Each query's turn on a worker serialises every
      sensor of it the query asks for (tens of ms for 3000 tracks), so a frame can wait
      behind such a turn as well as a 3000-box frame."""
    lat = calm.s.answer_times(list(range(calm.n)))
    base, flood, queries = lat[: phases[0]], lat[phases[0] : phases[1]], lat[phases[1] :]
    return {
        "before p50": float(np.median(base)),
        "flood p50": float(np.median(flood)),
        "flood max": max(flood),
        "queries max": max(queries),
    }


def evicted(svc: ServiceProcess, names: tuple[str, str]) -> bool:
    return any(
        e.get("event") == "sensor_evicted" and (e.get("vehicle"), e.get("sensor")) == names
        for e in svc.logs()
    )


def test_a_flood_never_delays_a_new_or_returning_sensor_nor_a_calm_one(
    tmp_path: Path,
) -> None:
    # The placement this test is about (crc32 of the key, two workers by default): the new
    # sensor and the calm one share the flood's worker; the returning sensor has the other.
    where = {n: worker_index(KEYS.detections(*n), 2) for n in (FLOODED, NEW, CALM, EVICTED)}
    assert where[NEW] == where[CALM] == where[FLOODED] != where[EVICTED], where
    env = {"SIMPLETRACK_SENSOR_IDLE_S": "1.0"}  # evicted after 1-1.5 s without a frame
    svc = start_service(tmp_path, env=env, instance=INSTANCE)
    sensors: list[Sensor] = []
    floods: list[subprocess.Popen[str]] = []
    report: dict[str, list[float]] = {}
    try:
        calm, back, new, queried = (Sensor(svc.endpoint, n) for n in (CALM, EVICTED, NEW, QUERIED))
        sensors += [calm, back, new, queried]
        streaming = Calm(calm)
        streaming.start()
        # The returning sensor is heard once (3000 boxes), then falls silent.
        report["before"] = two_heavy_frames(back, 0)
        time.sleep(2.0)  # the calm sensor's baseline
        phases = [streaming.n]

        floods.append(flooder(svc.endpoint, "garbage", KEYS.detections(*FLOODED)))
        assert floods[0].stdout is not None and floods[0].stdout.readline().startswith("done")
        report["new"] = two_heavy_frames(new, 0)
        assert evicted(svc, EVICTED), "the returning sensor's state was not evicted"
        report["evicted"] = two_heavy_frames(back, 2)

        selectors = [KEYS.snapshot(INSTANCE), KEYS.status(INSTANCE)]  # every sensor's, and all
        phases.append(streaming.n)
        floods.append(flooder(svc.endpoint, "queries", *selectors))
        time.sleep(1.0)  # the queries' flood at its pace
        report["during queries"] = two_heavy_frames(queried, 0)

        streaming.stopped.set()
        streaming.join()
        for proc in floods:
            stop(proc)
        calm_ms = {k: round(v * 1e3, 1) for k, v in calm_figures(streaming, phases).items()}
        m = svc.metrics()
        rejected = metric(m, "simpletrack_frames_rejected_total", reason="malformed")
        refused = metric(m, "simpletrack_queries_refused_total")
        print({k: [round(x, 3) for x in v] for k, v in report.items()})
        print(f"calm ({streaming.n} frames), ms: {calm_ms}")
        print(f"floods: {rejected:.0f} refused as malformed, {refused:.0f} queries as busy")
        assert rejected > 1000 and refused > 0  # both floods did reach the service
        for what in ("new", "evicted", "during queries"):
            assert max(report[what]) <= ANSWER_S, report
        for s in (back, new, queried, calm):
            assert not s.errors, s.errors[:3]
        assert calm_ms["flood p50"] <= 2 * calm_ms["before p50"] + 20, calm_ms
        assert calm_ms["flood max"] <= 500, calm_ms
        assert calm_ms["queries max"] <= ANSWER_S * 1e3, calm_ms
    finally:
        for proc in floods:
            if proc.poll() is None:
                stop(proc)
        for s in sensors:
            s.close()
        assert svc.stop() == 0
