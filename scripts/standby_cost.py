"""What each role costs per frame: a member alone, and a pair in which one member owns every
sensor and the other stands by for all of them.

The sensors' names are picked so that member ``a`` ranks first for each (server/group.py),
so ``b`` is a pure standby (it hears each frame, each tracks message and each checkpoint
and tracks nothing). A planner-like subscriber hears every tracks message in both setups,
so the owner publishes to the network in both. ``--sensors`` DetectionPublishers put
synthetic frames (``--boxes`` boxes) at 10 Hz; each member's CPU (user + system, from
/proc) over ``--seconds`` after a warm-up, per frame. Rows alternate alone / pair.

    .venv/bin/python scripts/standby_cost.py --sensors 40 --rounds 3
"""

from __future__ import annotations

import argparse
import signal
import subprocess
import sys
import time

import zenoh

from simpletrack.bench.loadgen import synthetic_box_arrays
from simpletrack.bench.service import cpu_seconds
from simpletrack.client.publisher import DetectionPublisher
from simpletrack.server.group import ranking
from simpletrack.session import ZenohOptions

PREFIX, RATE_HZ, WARMUP_S, START_S = "cost", 10.0, 5.0, 6.0
ENDPOINTS = {"a": "tcp/127.0.0.1:17501", "b": "tcp/127.0.0.1:17502"}


def serve(instance: str, peers: list[str]) -> subprocess.Popen[bytes]:
    cmd = [sys.executable, "-m", "simpletrack.cli.main", "serve", "--instance", instance]
    cmd += ["--listen", ENDPOINTS[instance], "--prefix", PREFIX, "--preset", "nuscenes"]
    cmd += ["--metrics-port", str(17510 + ord(instance[0]) - ord("a")), "--log-level", "error"]
    for p in peers:
        cmd += ["--connect", ENDPOINTS[p]]
    return subprocess.Popen(cmd)


def owned_by_a(n: int) -> list[str]:
    names: list[str] = []
    i = 0
    while len(names) < n:
        if ranking(["a", "b"], f"v/s{i:04d}")[0] == "a":
            names.append(f"s{i:04d}")
        i += 1
    return names


def run(pair: bool, sensors: int, boxes: int, seconds: float) -> str:
    members = {"a": serve("a", ["b"] if pair else [])}
    if pair:
        members["b"] = serve("b", ["a"])
    try:
        time.sleep(START_S)
        session = zenoh.open(ZenohOptions(connect=[ENDPOINTS["a"]]).to_config())
        heard = session.declare_subscriber(f"{PREFIX}/*/*/tracks", lambda s: None)
        pubs = [
            DetectionPublisher(session, "v", s, classes=("car",), prefix=PREFIX)
            for s in owned_by_a(sensors)
        ]
        frames = synthetic_box_arrays(boxes, 0)
        start, k, marks, k0, t0 = time.perf_counter(), 0, {}, 0, 0.0
        while True:
            elapsed = time.perf_counter() - start
            if elapsed > WARMUP_S and not marks:
                marks, k0, t0 = (
                    {n: cpu_seconds(p.pid) for n, p in members.items()},
                    k,
                    time.perf_counter(),
                )
            if elapsed > WARMUP_S + seconds:
                break
            wait = start + k / RATE_HZ - time.perf_counter()
            if wait > 0:
                time.sleep(wait)
            for p in pubs:
                p.publish_arrays(frames[k % len(frames)])
            k += 1
        n_frames, span = (k - k0) * sensors, time.perf_counter() - t0
        used = {n: cpu_seconds(p.pid) - marks[n] for n, p in members.items()}
        for p in pubs:
            p.close()
        heard.undeclare()
        session.close()
    finally:
        for p in members.values():
            p.send_signal(signal.SIGTERM)
        for p in members.values():
            p.wait(30)
    roles = {"a": "owner", "b": "standby"}
    cells = [
        f"{roles[n]} {v / n_frames * 1e3:.3f} ms/frame ({v / span:.3f} cores)"
        for n, v in used.items()
    ]
    total = sum(used.values()) / n_frames * 1e3
    return (
        f"{'pair ' if pair else 'alone'} {sensors} sensors: "
        + ", ".join(cells)
        + f"; total {total:.3f} ms/frame"
    )


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--sensors", type=int, default=40)
    ap.add_argument("--boxes", type=int, default=128)
    ap.add_argument("--seconds", type=float, default=10.0)
    ap.add_argument("--rounds", type=int, default=3)
    a = ap.parse_args()
    for _ in range(a.rounds):
        for pair in (False, True):
            print(run(pair, a.sensors, a.boxes, a.seconds), flush=True)


if __name__ == "__main__":
    main()
