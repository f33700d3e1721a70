"""End-to-end latency of ``simpletrack serve`` with nuScenes-sized frames at a fixed rate.

    .venv/bin/python -m tests.bench_latency --sensors 1 --seconds 20
    .venv/bin/python -m tests.bench_latency --sensors 50 --seconds 20

Starts the service (preset nuscenes) as a subprocess on 127.0.0.1, then publishes real
CenterPoint frames from ``../shared/data/nuscenes`` (every class, ~128 boxes per frame on
average; sensor i replays scene i in a loop) for N sensors at 10 Hz each, their phases spread
evenly over the period. Latency = tracks received by the subscriber − ``stamp_ns``, which the
publisher sets to its wall clock right before ``put`` (same host, same clock). Frames the
service shed or refused are counted, not timed. The first second is a warm-up.
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
import threading
import time
from pathlib import Path

import numpy as np
import zenoh

from clients.nuscenes_io import TYPE_NAMES, camera_to_tracker
from schemas import BoxArrays, decode_track_frame, encode_detection_frame
from service.zenoh_config import open_session
from tests.service_helpers import DATA, start_service

NUSCENES = DATA / "nuscenes" / "centerpoint_val"
CLASSES = tuple(TYPE_NAMES[t] for t in sorted(TYPE_NAMES))
UNTRACKED = ("construction_vehicle", "barrier", "traffic_cone")  # not in the nuscenes preset


def load_scene(path: Path) -> list[BoxArrays]:
    raw = np.loadtxt(path, delimiter=",", ndmin=2)
    frame = raw[:, 0].astype(np.int64)
    params = camera_to_tracker(raw[:, 7:14]).astype(np.float32)
    out = []
    for k in range(int(frame.max()) + 1):
        rows = np.flatnonzero(frame == k)
        out.append(
            BoxArrays(
                classes=CLASSES,
                class_index=(raw[rows, 1].astype(np.int32) - 1),
                center=params[rows, 0:3],
                size=params[rows, 4:7],
                yaw=params[rows, 3],
                score=raw[rows, 6].astype(np.float32),
            )
        )
    return out


def run(
    sensors: int, seconds: float, rate: float, workers: int, queue_size: int
) -> dict[str, object]:
    scenes = [load_scene(p) for p in sorted(NUSCENES.glob("scene-*.txt"))[:sensors]]
    boxes_per_frame = float(np.mean([len(b) for s in scenes for b in s]))
    received: dict[tuple[str, int], int] = {}
    errors: dict[str, int] = {}
    lock = threading.Lock()

    def on_tracks(sample: zenoh.Sample) -> None:
        now = time.time_ns()
        out = decode_track_frame(
            sample.payload.to_bytes(),
        )
        if isinstance(out, tuple):
            with lock:
                received[(out[0].sensor, out[0].seq)] = now - out[0].stamp_ns

    def on_errors(sample: zenoh.Sample) -> None:
        with lock:
            key = str(sample.key_expr)
            errors[key] = errors.get(key, 0) + 1

    with tempfile.TemporaryDirectory() as tmp:
        svc = start_service(
            Path(tmp),
            "--preset",
            "nuscenes",
            "--workers",
            str(workers),
            "--log-level",
            "error",
            env={
                "SIMPLETRACK_IGNORE_CLASSES": json.dumps(UNTRACKED),
                "SIMPLETRACK_QUEUE_SIZE": str(queue_size),
            },
            instance="bench",
        )
        session = open_session(mode="peer", connect=[svc.endpoint])
        try:
            session.declare_subscriber("fleet/*/*/tracks", on_tracks)
            session.declare_subscriber("fleet/*/*/errors", on_errors)
            pubs = []
            for i in range(sensors):
                pub = session.declare_publisher(
                    f"fleet/bench/s{i:03d}/detections",
                    congestion_control=zenoh.CongestionControl.BLOCK,
                )
                while not pub.matching_status.matching:
                    time.sleep(0.01)
                pubs.append(pub)
            time.sleep(0.5)
            period = 1.0 / rate
            ticks = int(seconds * rate)
            sent_at: dict[tuple[str, int], float] = {}
            t0 = time.perf_counter() + 0.2
            for tick in range(ticks):
                for i in range(sensors):
                    due = t0 + tick * period + i * period / sensors
                    delay = due - time.perf_counter()
                    if delay > 0:
                        time.sleep(delay)
                    frames = scenes[i]
                    payload = encode_detection_frame(
                        vehicle="bench",
                        sensor=f"s{i:03d}",
                        seq=tick,
                        stamp_ns=time.time_ns(),
                        frame_id="lidar",
                        boxes=frames[tick % len(frames)],
                    )
                    pubs[i].put(payload)
                    sent_at[(f"s{i:03d}", tick)] = due
            time.sleep(3.0)  # stragglers
            metrics = svc.metrics()
        finally:
            session.close()  # type: ignore[no-untyped-call]
            svc.stop()

    warm = int(rate)  # the first second
    with lock:
        lat = np.array([v for (s, seq), v in received.items() if seq >= warm], dtype=np.float64)
        n_err = sum(errors.values())
    expected = sensors * (ticks - warm)
    track_sum = metrics.get('simpletrack_stage_seconds_sum{stage="track"}', 0.0)
    track_count = metrics.get('simpletrack_stage_seconds_count{stage="track"}', 1.0)
    return {
        "sensors": sensors,
        "rate_hz": rate,
        "seconds": seconds,
        "workers": workers,
        "queue_size": queue_size,
        "boxes_per_frame": round(boxes_per_frame, 1),
        "frames_sent": sensors * ticks,
        "frames_tracked": len(received),
        "frames_refused": n_err,
        "timed": len(lat),
        "timed_of_expected": f"{len(lat)}/{expected}",
        "p50_ms": round(float(np.percentile(lat, 50)) / 1e6, 2) if len(lat) else None,
        "p90_ms": round(float(np.percentile(lat, 90)) / 1e6, 2) if len(lat) else None,
        "p99_ms": round(float(np.percentile(lat, 99)) / 1e6, 2) if len(lat) else None,
        "max_ms": round(float(lat.max()) / 1e6, 2) if len(lat) else None,
        "track_stage_mean_ms": round(1e3 * track_sum / max(track_count, 1.0), 2),
        "dropped_queue_full": metrics.get(
            'simpletrack_frames_dropped_total{reason="dropped_queue_full"}', 0.0
        ),
    }


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--sensors", type=int, default=1)
    parser.add_argument("--seconds", type=float, default=20.0)
    parser.add_argument("--rate", type=float, default=10.0, help="frames per second per sensor")
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--queue-size", type=int, default=64, help="per worker")
    args = parser.parse_args(argv)
    if not NUSCENES.is_dir():
        print(f"no nuScenes detections under {NUSCENES}", file=sys.stderr)
        return 2
    print(json.dumps(run(args.sensors, args.seconds, args.rate, args.workers, args.queue_size)))
    return 0


if __name__ == "__main__":
    sys.exit(main())
