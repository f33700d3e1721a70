"""The burst a router outage leaves behind (``python -m simpletrack.bench.outage_burst``).

S sensors (one vehicle each, the client library's ``DetectionPublisher``: an advanced
publisher with its cache) stream at 10 Hz through a Zenoh router in a subprocess to a
service that is a client of that router. The router is SIGKILLed for ``--outage`` seconds and
started again; the vehicles' caches then hand the service every frame of the outage at once.
Measured from the service's /metrics, polled every 20 ms: the bytes the burst held on the
service's burst budget at peak (``simpletrack_burst_bytes_peak``), the frames kept beyond
``queue_size`` (``simpletrack_burst_frames_total``), how long from the router's return until
the budget was empty again (the drain), and what was tracked, dropped (by reason) or missed.

It measures; it does not judge (tests/faults/test_recovered_frames_are_never_shed.py does).
"""

from __future__ import annotations

import argparse
import contextlib
import json
import os
import signal
import subprocess
import sys
import tempfile
import threading
import time
import urllib.request
from pathlib import Path
from typing import Any

import zenoh

from simpletrack.client import Box, DetectionPublisher
from simpletrack.client.publisher import box_list_to_arrays
from simpletrack.session import ZenohOptions, open_session
from simpletrack.spawn import ROOT, free_port
from simpletrack.wire.codec import decode_message, encode_detection_frame
from simpletrack.wire.models import FrameError

ROUTER_CODE = """
import signal, sys, threading, zenoh
c = zenoh.Config()
c.insert_json5("mode", '"router"')
c.insert_json5("listen/endpoints", '["%s"]' % sys.argv[1])
c.insert_json5("connect/endpoints", "[]")
c.insert_json5("scouting/multicast/enabled", "false")
session = zenoh.open(c)
stop = threading.Event()
signal.signal(signal.SIGTERM, lambda *_: stop.set())
print("up", flush=True)
stop.wait()
session.close()
"""
PERIOD_S = 0.1


def start_router(endpoint: str) -> subprocess.Popen[bytes]:
    proc = subprocess.Popen(
        [sys.executable, "-c", ROUTER_CODE, endpoint],
        stdout=subprocess.PIPE,
        stderr=subprocess.DEVNULL,
    )
    assert proc.stdout is not None
    if proc.stdout.readline().strip() != b"up":
        raise RuntimeError(f"router on {endpoint} did not come up")
    return proc


def scrape(port: int) -> dict[str, float]:
    with urllib.request.urlopen(f"http://127.0.0.1:{port}/metrics", timeout=5) as r:
        text = r.read().decode()
    out = {}
    for line in text.splitlines():
        if line and not line.startswith("#"):
            name, _, value = line.rpartition(" ")
            out[name] = float(value)
    return out


def ready(port: int) -> bool:
    try:
        with urllib.request.urlopen(f"http://127.0.0.1:{port}/readyz", timeout=5) as r:
            return int(r.status) == 200
    except OSError:
        return False


def boxes(k: int, n: int) -> list[Box]:
    """n cars 6 m apart driving along +x at 10 m/s."""
    return [Box(10.0 + k, 6.0 * j, 0.8, 0.0, 4.0, 1.8, 1.6, 0.9, "Car") for j in range(n)]


class Notices:
    """The seqs named by the service's drop notices (``dropped_*``; ``missed`` names none)."""

    def __init__(self) -> None:
        self.seqs: list[int] = []
        self._lock = threading.Lock()

    def on_error(self, sample: zenoh.Sample) -> None:
        err = decode_message(sample.payload.to_bytes(), FrameError)
        if isinstance(err, FrameError) and err.reason.value.startswith("dropped"):
            with self._lock:
                self.seqs += [s for s in (err.seqs or [err.seq]) if s is not None]

    def shed(self, first: int, end: int) -> int:
        """How many frames published from seq ``first`` to ``end`` (the outage) were shed."""
        with self._lock:
            return sum(first <= s < end for s in self.seqs)


class Fleet(threading.Thread):
    """Every sensor's frame each period, from one thread (paced: an outage never slows it)."""

    def __init__(self, pubs: list[DetectionPublisher], n_boxes: int) -> None:
        super().__init__(daemon=True)
        self.pubs, self.n_boxes = pubs, n_boxes
        self.ticks = 0
        self.halt = threading.Event()

    def run(self) -> None:
        t0 = time.monotonic()
        while not self.halt.is_set():
            b = boxes(self.ticks, self.n_boxes)
            for pub in self.pubs:
                pub.publish(b)
            self.ticks += 1
            self.halt.wait(max(0.0, t0 + self.ticks * PERIOD_S - time.monotonic()))


def run(
    sensors: int, outage_s: float, n_boxes: int, cache: int, extra: list[str]
) -> dict[str, Any]:
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    metrics_port = free_port()
    router = start_router(endpoint)
    log_path = Path(tempfile.mkdtemp(prefix="outage-burst-")) / "service.log"
    cmd = [
        sys.executable, "-m", "simpletrack.cli.main", "serve", "--mode", "client",
        "--connect", endpoint, "--metrics-port", str(metrics_port),
        "--instance", "outage-burst", *extra,
    ]  # fmt: skip
    env = {**os.environ, "SIMPLETRACK_LOG_FORMAT": "json", "SIMPLETRACK_LOG_LEVEL": "warning"}
    with open(log_path, "wb") as log:
        service = subprocess.Popen(cmd, cwd=ROOT, env=env, stdout=log, stderr=log)
    options = ZenohOptions(mode="client", connect=[endpoint], connect_timeout_ms=-1)
    session = open_session(options)
    pubs: list[DetectionPublisher] = []
    fleet: Fleet | None = None
    try:
        deadline = time.monotonic() + 60
        while True:
            if ready(metrics_port):
                break
            if time.monotonic() > deadline or service.poll() is not None:
                raise RuntimeError(f"service not ready; its log: {log_path}")
            time.sleep(0.1)
        pubs = [
            DetectionPublisher(
                session, f"veh{i:03d}", "lidar", classes=("Car",), cache_frames=cache
            )
            for i in range(sensors)
        ]
        for pub in pubs:
            pub.wait_for_service(10)
        # Every frame the service gave up, by seq: were any of them recovered ones?
        notices = Notices()
        errors_sub = session.declare_subscriber("fleet/*/*/errors", notices.on_error)
        fleet = Fleet(pubs, n_boxes)
        fleet.start()
        time.sleep(3.0)  # warm: every sensor's usual delay known, trackers started
        before = scrape(metrics_port)
        router.send_signal(signal.SIGKILL)
        router.wait()
        t_kill, tick_kill = time.monotonic(), fleet.ticks
        time.sleep(outage_s)
        router = start_router(endpoint)
        t_back, tick_back = time.monotonic(), fleet.ticks
        peak_depth = 0.0
        drained_at: float | None = None
        seen_burst = False
        while time.monotonic() - t_back < 120:
            m = scrape(metrics_port)
            in_use = m.get("simpletrack_burst_bytes", 0.0)
            peak_depth = max(peak_depth, m.get("simpletrack_queue_depth", 0.0))
            seen_burst = seen_burst or in_use > 0
            if seen_burst and in_use == 0 and drained_at is None:
                drained_at = time.monotonic()
            if drained_at is not None and time.monotonic() - drained_at > 2.0:
                break
            if in_use > 0:
                drained_at = None
            time.sleep(0.02)
        fleet.halt.set()
        fleet.join(5)
        time.sleep(1.0)
        after = scrape(metrics_port)
        sent = fleet.ticks * sensors
        frame_bytes = len(
            encode_detection_frame(
                vehicle="veh000", sensor="lidar", seq=sent, stamp_ns=time.time_ns(),
                frame_id="lidar", boxes=box_list_to_arrays(boxes(0, n_boxes), ("Car",)),
            )
        )  # fmt: skip

        def delta(name: str) -> float:
            return after.get(name, 0.0) - before.get(name, 0.0)

        dropped = {
            k.split('"')[1]: v - before.get(k, 0.0)
            for k, v in after.items()
            if k.startswith("simpletrack_frames_dropped_total")
        }
        errors_sub.undeclare()  # type: ignore[no-untyped-call]
        return {
            "sensors": sensors,
            "outage_s": outage_s,
            "router_down_s": round(t_back - t_kill, 2),
            "boxes_per_frame": n_boxes,
            "frame_bytes": frame_bytes,
            "cache_frames": cache,
            "frames_sent": sent,
            "frames_held_by_vehicles": sum(p.held for p in pubs),
            "frames_lost_by_caches": sum(p.lost for p in pubs),
            "frames_received": after.get("simpletrack_frames_received_total", 0.0),
            "frames_tracked": after.get("simpletrack_frames_tracked_total", 0.0),
            "dropped_before_outage": sum(
                v for k, v in before.items() if k.startswith("simpletrack_frames_dropped_total")
            ),
            "dropped_since_outage": dropped,
            "outage_seqs": [tick_kill, tick_back + 20],  # + the 2 s the links take to return
            "outage_frames_shed": notices.shed(tick_kill, tick_back + 20),
            "burst_frames_kept": delta("simpletrack_burst_frames_total"),
            "burst_bytes_peak": after.get("simpletrack_burst_bytes_peak", 0.0),
            "burst_bytes_limit": after.get("simpletrack_burst_bytes_limit", 0.0),
            "queue_depth_peak": peak_depth,
            "drain_s": None if drained_at is None else round(drained_at - t_back, 2),
            "service_rss_mb": after.get("process_resident_memory_bytes", 0.0) / 2**20,
            "cpus": os.cpu_count(),
            "service_log": str(log_path),
        }
    finally:
        if fleet is not None:
            fleet.halt.set()
        for pub in pubs:
            with contextlib.suppress(Exception):
                pub.close()
        session.close()  # type: ignore[no-untyped-call]
        service.send_signal(signal.SIGTERM)
        try:
            service.wait(30)
        except subprocess.TimeoutExpired:
            service.kill()
        router.terminate()
        router.wait(10)


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(
        prog="python -m simpletrack.bench.outage_burst", description=__doc__
    )
    p.add_argument("--sensors", type=int, default=100)
    p.add_argument("--outage", type=float, default=10.0, help="seconds the router is down")
    p.add_argument("--boxes", type=int, default=6, help="cars per frame")
    p.add_argument("--cache", type=int, default=100, help="frames each vehicle caches")
    p.add_argument("--json", type=Path, help="also write the figures to this file")
    p.add_argument("serve", nargs=argparse.REMAINDER, help="-- then extra `serve` flags")
    args = p.parse_args(argv)
    extra = [a for a in args.serve if a != "--"]
    result = run(args.sensors, args.outage, args.boxes, args.cache, extra)
    for key, value in result.items():
        print(f"{key:>24}: {value}")
    if args.json is not None:
        args.json.write_text(json.dumps(result, indent=2) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
