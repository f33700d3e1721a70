"""What each role costs per frame: a member alone, and a pair in which one member owns every
sensor and the other stands by for all of them.

The sensors' names are picked so that member ``a`` ranks first for each (server/group.py),
so ``b`` is a pure standby (it hears each frame, each tracks message and each checkpoint
and tracks nothing). A planner-like subscriber hears every tracks message in both setups,
so the owner publishes to the network in both. ``--sensors`` DetectionPublishers put
synthetic frames (``--boxes`` boxes) at 10 Hz; each member's CPU (user + system, from
/proc) over ``--seconds`` after a warm-up, per frame. Rows alternate alone / pair.
``--fused``: ``--sensors`` fused vehicles instead, each a lidar (the frame) and a front
camera (the boxes it sees, half a period later), the members fusing them (the service
benchmark's fusion settings); per frame is then per sensor frame.

    .venv/bin/python scripts/standby_cost.py --sensors 40 --rounds 3
    .venv/bin/python scripts/standby_cost.py --sensors 20 --fused --rounds 3
"""

from __future__ import annotations

import argparse
import dataclasses
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import zenoh

from simpletrack.bench.fused import in_front_view
from simpletrack.bench.loadgen import IDENTITY, synthetic_box_arrays
from simpletrack.bench.service import FUSION_CONFIG, cpu_seconds
from simpletrack.client.publisher import DetectionPublisher
from simpletrack.server.group import ranking
from simpletrack.session import ZenohOptions
from simpletrack.wire import BoxArrays
from simpletrack.wire.keys import VEHICLE_STREAM

PREFIX, RATE_HZ, WARMUP_S, START_S = "cost", 10.0, 5.0, 6.0
ENDPOINTS = {"a": "tcp/127.0.0.1:17501", "b": "tcp/127.0.0.1:17502"}


def serve(instance: str, peers: list[str], config: Path | None) -> subprocess.Popen[bytes]:
    cmd = [sys.executable, "-m", "simpletrack.cli.main", "serve", "--instance", instance]
    cmd += ["--listen", ENDPOINTS[instance], "--prefix", PREFIX, "--preset", "nuscenes"]
    cmd += ["--metrics-port", str(17510 + ord(instance[0]) - ord("a")), "--log-level", "error"]
    if config is not None:
        cmd += ["--config", str(config)]
    for p in peers:
        cmd += ["--connect", ENDPOINTS[p]]
    return subprocess.Popen(cmd)


def owned_by_a(n: int, fused: bool) -> list[tuple[str, str]]:
    """(vehicle, sensor) of ``n`` sensors (fused: the lidar and the camera of ``n``
    vehicles) whose stream ranks ``a`` first."""
    names: list[tuple[str, str]] = []
    i = 0
    while len(names) < n * (2 if fused else 1):
        if not fused and ranking(["a", "b"], f"v/s{i:04d}")[0] == "a":
            names.append(("v", f"s{i:04d}"))
        if fused and ranking(["a", "b"], f"v{i:04d}/{VEHICLE_STREAM}")[0] == "a":
            names += [(f"v{i:04d}", "lidar"), (f"v{i:04d}", "camera")]
        i += 1
    return names


def front_view(boxes: BoxArrays) -> BoxArrays:
    """The boxes the benchmarks' front camera sees (bench/fused.py ``in_front_view``)."""
    keep = in_front_view(boxes.center[:, 0], boxes.center[:, 1])
    rows = {f: getattr(boxes, f)[keep] for f in ("class_index", "center", "size", "yaw", "score")}
    return dataclasses.replace(boxes, **rows, velocity=None)


def run(pair: bool, sensors: int, boxes: int, seconds: float, fused: bool) -> str:
    config = None
    if fused:
        config = Path(tempfile.mkdtemp()) / "fusion.toml"
        config.write_text(FUSION_CONFIG)
    members = {"a": serve("a", ["b"] if pair else [], config)}
    if pair:
        members["b"] = serve("b", ["a"], config)
    try:
        time.sleep(START_S)
        session = zenoh.open(ZenohOptions(connect=[ENDPOINTS["a"]]).to_config())
        answers = [0]
        # A fused vehicle's key's @vehicle chunk is matched only verbatim.
        key = f"{PREFIX}/*/{VEHICLE_STREAM}/tracks" if fused else f"{PREFIX}/*/*/tracks"
        heard = session.declare_subscriber(key, lambda s: answers.__setitem__(0, answers[0] + 1))
        pubs = [
            DetectionPublisher(
                session,
                v,
                s,
                classes=("car",),
                prefix=PREFIX,
                extrinsic=IDENTITY if fused else None,
            )
            for v, s in owned_by_a(sensors, fused)
        ]
        frames = synthetic_box_arrays(boxes, 0)
        seen = [front_view(f) for f in frames]
        period_ns = int(1e9 / RATE_HZ)
        start, k, marks, k0, t0, a0 = time.perf_counter(), 0, {}, 0, 0.0, 0
        while True:
            elapsed = time.perf_counter() - start
            if elapsed > WARMUP_S and not marks:
                marks, k0, t0, a0 = (
                    {n: cpu_seconds(p.pid) for n, p in members.items()},
                    k,
                    time.perf_counter(),
                    answers[0],
                )
            if elapsed > WARMUP_S + seconds:
                break
            wait = start + k / RATE_HZ - time.perf_counter()
            if wait > 0:
                time.sleep(wait)
            if not fused:
                for p in pubs:
                    p.publish_arrays(frames[k % len(frames)])
            else:  # each camera half a period after its lidar, stamped so
                stamp = time.time_ns()
                for p in pubs[0::2]:
                    p.publish_arrays(frames[k % len(frames)], stamp_ns=stamp)
                time.sleep(0.5 / RATE_HZ)
                for p in pubs[1::2]:
                    p.publish_arrays(seen[k % len(seen)], stamp_ns=stamp + period_ns // 2)
            k += 1
        n_frames, span = (k - k0) * len(pubs), time.perf_counter() - t0
        n_answers = answers[0] - a0
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
        f"{'pair ' if pair else 'alone'} {sensors} {'vehicles' if fused else 'sensors'}: "
        + ", ".join(cells)
        + f"; total {total:.3f} ms/frame; {n_answers / n_frames:.2f} tracks messages a frame"
    )


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--sensors", type=int, default=40)
    ap.add_argument("--boxes", type=int, default=128)
    ap.add_argument("--seconds", type=float, default=10.0)
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--fused", action="store_true", help="fused vehicles of a lidar and a camera")
    a = ap.parse_args()
    for _ in range(a.rounds):
        for pair in (False, True):
            print(run(pair, a.sensors, a.boxes, a.seconds, a.fused), flush=True)


if __name__ == "__main__":
    main()
