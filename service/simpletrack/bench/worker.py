"""A service worker's per-frame path, in-process: a real ``Service`` (its Zenoh session, custody,
registry, outbox and metrics, one worker), fed frames by this thread as its worker thread feeds
them from its queue, with nothing else running: no load generator, no receive, no thread hop.

What it measures is the CPU the worker spends on a frame (``time.thread_time_ns``), which on a
shared machine varies far less than a whole service's CPU per frame under a load generator
(``bench service``), so one change to the path can be told from another by a few percent. It
leaves out what the worker does not do: Zenoh's receiving and sending threads, the intake's
callback, the wake of the worker, and what threads sharing the interpreter lock cost each
other. ``bench service`` measures those.

Two passes over the same sensors, after a warm-up: a clean one (the CPU per frame) and one with
timing shims around each stage of the path (``STAGES``; the shims' own cost lands in the stages,
so the stages come from that pass and the total from the clean one). A stage the code no longer
has fails the run (``MissingStageTarget``) instead of moving its cost to "other".
"""

from __future__ import annotations

import statistics
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from simpletrack.bench import loadgen
from simpletrack.bench.stages import StageTimer
from simpletrack.datasets.nuscenes import scene_files
from simpletrack.spawn import free_port

if TYPE_CHECKING:  # the server is imported when a run starts, not with the CLI
    from simpletrack.server.worker import Worker

# (stage, module, attribute path): the order a frame goes through the worker.
STAGES: tuple[tuple[str, str, str], ...] = (
    ("custody", "simpletrack.server.custody", "Custody.view"),
    ("custody", "simpletrack.server.custody_machine", "CustodyMachine.frame"),
    ("decode", "simpletrack.server.worker", "decode_detection_frame"),
    ("plausibility", "simpletrack.server.worker", "Worker._plausible"),
    ("order", "simpletrack.server.worker", "check_order"),
    ("order", "simpletrack.server.sensors", "SensorState.keep_undo"),
    ("to_core", "simpletrack.server.worker", "frame_from_wire"),
    ("step", "simpletrack.core.tracker", "Tracker.step"),
    ("to_wire", "simpletrack.server.worker", "pack_tracks_checked"),
    ("encode", "simpletrack.server.worker", "encode_track_frame"),
    ("put", "simpletrack.server.outbox", "Outbox.tracks"),
    ("metrics", "prometheus_client.metrics", "Histogram.observe"),
    ("metrics", "prometheus_client.metrics", "Counter.inc"),
    ("metrics", "prometheus_client.metrics", "Gauge.inc"),
)
OTHER = "other"  # the worker's own glue: the clean pass's CPU less the stages'
PREFIX = "bench-worker"
SENSOR = "lidar"


@dataclass(frozen=True)
class WorkerOptions:
    sensors: int = 60
    frames: int = 60  # per sensor and pass
    warmup: int = 20  # per sensor, before the passes
    source: str = "synthetic"  # or "nuscenes"
    data: Path | None = None  # holds nuscenes/centerpoint_val/ (source nuscenes)
    synthetic_boxes: int = 128

    def __post_init__(self) -> None:
        if not 1 <= self.sensors <= 10_000:
            raise ValueError(f"sensors must be in 1..10000, got {self.sensors}")
        if not 2 <= self.frames <= 100_000:
            raise ValueError(f"frames must be in 2..100000, got {self.frames}")
        if not 0 <= self.warmup <= 100_000:
            raise ValueError(f"warmup must be in 0..100000, got {self.warmup}")
        if not 1 <= self.synthetic_boxes <= 10_000:
            raise ValueError(f"synthetic_boxes must be in 1..10000, got {self.synthetic_boxes}")
        if self.source not in ("nuscenes", "synthetic"):
            raise ValueError(f"source must be nuscenes or synthetic, got {self.source!r}")
        if self.source == "nuscenes" and self.data is None:
            raise ValueError("source nuscenes needs data (the folder holding nuscenes/)")


def box_streams(opts: WorkerOptions) -> list[list[dict[str, Any]]]:
    """Each distinct stream's box columns per frame; sensor i replays stream i % len, as the
    load generator's sensors do."""
    if opts.source == "synthetic":
        arrays = [loadgen.synthetic_box_arrays(opts.synthetic_boxes, s) for s in range(4)]
    else:
        assert opts.data is not None
        folder = opts.data / "nuscenes" / "centerpoint_val"
        files = list(scene_files(folder))[: opts.sensors]
        if not files:
            raise FileNotFoundError(f"no nuScenes scene files in {folder}")
        arrays = [loadgen.scene_box_arrays(p) for p in files]
    return [[loadgen.box_columns(b) for b in stream] for stream in arrays]


def _settings(endpoint: str) -> Any:
    from simpletrack.server.settings import ServiceSettings

    return ServiceSettings(
        preset="nuscenes",
        ignore_classes=list(loadgen.UNTRACKED),
        instance=PREFIX,
        prefix=PREFIX,
        workers=1,
        zenoh={"listen": [endpoint]},
    )


class _Feeder:
    """Frames for the worker, as the fleet would send them: each sensor's next frame in turn,
    stamped now (so no plausibility check flags it), its seq one past the last."""

    def __init__(self, streams: list[list[dict[str, Any]]], sensors: int) -> None:
        from simpletrack.server.intake import Inbound
        from simpletrack.wire.keys import Keys

        self._inbound = Inbound
        keys = Keys(PREFIX)
        self.sensors = [
            (f"v{i:04d}", keys.detections(f"v{i:04d}", SENSOR), streams[i % len(streams)])
            for i in range(sensors)
        ]
        self.seq = 0

    def round(self) -> list[Any]:
        """The next frame of every sensor (payloads built here, outside any timing)."""
        self.seq += 1
        out = []
        for vehicle, key, frames in self.sensors:
            cols = frames[(self.seq - 1) % len(frames)]
            stamp = time.time_ns() - 2_000_000
            payload = loadgen.detection_payload(vehicle, SENSOR, self.seq, stamp, cols)
            out.append((key, payload))
        return out

    def item(self, key: str, payload: bytes) -> Any:
        return self._inbound(key, payload, time.time_ns(), time.perf_counter())


def _pass(worker: Worker, feeder: _Feeder, frames: int, cpu: list[int] | None) -> None:
    for _ in range(frames):
        for key, payload in feeder.round():
            item = feeder.item(key, payload)
            t0 = time.thread_time_ns()
            worker.handle(item)  # what the worker thread does with a queued frame
            if cpu is not None:
                cpu.append(time.thread_time_ns() - t0)


def run_worker_bench(
    opts: WorkerOptions, progress: Callable[[str], None] = print
) -> dict[str, Any]:
    from simpletrack.server.app import Service

    streams = box_streams(opts)
    boxes = float(np.mean([f["count"] for s in streams for f in s]))
    timer = StageTimer(STAGES)  # a stage the code no longer has fails here, before the start
    service = Service(_settings(f"tcp/127.0.0.1:{free_port()}"))
    service.start()
    try:
        worker = service._workers[0]
        feeder = _Feeder(streams, opts.sensors)
        progress(f"worker: {opts.sensors} sensors, {opts.warmup} frames each to warm up")
        _pass(worker, feeder, opts.warmup, None)
        progress(f"worker: clean pass, {opts.frames} frames per sensor")
        cpu: list[int] = []
        _pass(worker, feeder, opts.frames, cpu)
        progress(f"worker: shimmed pass, {opts.frames} frames per sensor")
        shimmed: list[int] = []
        with timer:
            _pass(worker, feeder, opts.frames, shimmed)
    finally:
        service.shutdown()
    return worker_figures(opts, boxes, cpu, shimmed, timer)


def worker_figures(
    opts: WorkerOptions,
    boxes: float,
    cpu: Sequence[int],
    shimmed: Sequence[int],
    timer: StageTimer,
) -> dict[str, Any]:
    frames = len(shimmed)
    stages_us = {s: timer.seconds[s] * 1e6 / frames for s in timer.seconds}
    mean_us = statistics.mean(cpu) / 1e3
    shimmed_mean_us = statistics.mean(shimmed) / 1e3
    stages_us[OTHER] = max(0.0, shimmed_mean_us - sum(stages_us.values()))
    return {
        "sensors": opts.sensors,
        "frames": len(cpu),
        "source": opts.source,
        "boxes_per_frame": round(boxes, 1),
        "cpu_us_per_frame": {
            "median": round(statistics.median(cpu) / 1e3, 1),
            "mean": round(mean_us, 1),
            "p99": round(float(np.percentile(cpu, 99)) / 1e3, 1),
        },
        "shimmed_mean_us": round(shimmed_mean_us, 1),
        "stages_us_per_frame": {s: round(v, 1) for s, v in stages_us.items()},
        "calls_per_frame": {s: round(n / frames, 2) for s, n in timer.calls.items()},
        "published": timer.calls["put"],  # each frame answered on its tracks key
        "shimmed_frames": frames,
    }


def worker_table(doc: dict[str, Any]) -> str:
    cpu = doc["cpu_us_per_frame"]
    stages = doc["stages_us_per_frame"]
    total = sum(stages.values())
    lines = [
        f"a worker's CPU per frame, in-process: {doc['sensors']} {doc['source']} sensors, "
        f"{doc['boxes_per_frame']:g} boxes a frame, {doc['frames']} frames: median "
        f"{cpu['median']:g} µs, mean {cpu['mean']:g} µs, p99 {cpu['p99']:g} µs",
        f"by stage (the shimmed pass, mean {doc['shimmed_mean_us']:g} µs a frame; "
        f"{doc['published']} of {doc['shimmed_frames']} frames published):",
        "| stage | µs per frame | share | calls per frame |",
        "|---|---|---|---|",
    ]
    for stage, us in stages.items():
        calls = doc["calls_per_frame"].get(stage)
        lines.append(
            f"| {stage} | {us:.1f} | {us / total:.0%} | {'—' if calls is None else f'{calls:g}'} |"
        )
    return "\n".join(lines)
