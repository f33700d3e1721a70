"""The tracker core alone: frames/s, per-frame latency and time per stage on the real loads
(nuScenes val, KITTI train), and a scaling sweep on synthetic frames.

A *stream* is what one ``Tracker`` sees: one nuScenes scene, one KITTI sequence. Each frame
is timed around ``Tracker.step`` only (files are parsed before timing starts). Each load is
run twice: once clean for the latency figures, once with the stage shims (stages.py) for
the breakdown, so shim overhead never inflates the headline numbers.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from simpletrack.bench.fused import bench_fused
from simpletrack.bench.stages import OTHER, StageTimer, resolve_targets
from simpletrack.bench.stats import power_law, summary_ms
from simpletrack.core import jit, solvers
from simpletrack.core.boxes import Boxes
from simpletrack.core.config import TieOrder, TrackerConfig, VerticalOverlap, preset
from simpletrack.core.frames import Frame
from simpletrack.core.tracker import Tracker
from simpletrack.datasets.kitti import KITTI_CLASSES, TRAIN_SEQUENCES, load_sequence
from simpletrack.datasets.nuscenes import read_scene, scene_files
from simpletrack.eval.cv import ALL_CANDIDATES

# The reference's speed, measured by its authors' code on this kind of machine (2 cores,
# shared); we cannot run it here. Source: ../shared/data/reference/README.md.
REFERENCE_SOURCE = (
    "../shared/data/reference/README.md (the reference's own code, this machine kind)"
)
REFERENCE_NUSCENES = {"p50_ms": 350.0, "p99_ms": 1600.0, "frames_per_s": 2.3}
REFERENCE_KITTI_FPS = {"Car": 58.0, "Pedestrian": 722.0, "Cyclist": 3286.0}
REFERENCE_KITTI_CAR = {"p50_ms": 9.9, "p99_ms": 88.0, "frames_per_s": 58.0}
GOAL_SPEEDUP = 50.0

DEFAULT_SIZES = (10, 50, 100, 200, 500, 1000)
SYNTHETIC_PERIOD_S = 0.5  # the nuscenes preset's frame period
TAIL_FROM = 100  # the growth exponent "at scale" is fitted from this many boxes up
MIN_TIMED = 3  # frames timed per sweep size however slow they are


@dataclass(frozen=True, slots=True)
class Load:
    """Streams of frames for one preset; each stream gets a fresh tracker."""

    name: str
    config: TrackerConfig
    classes: tuple[str, ...]
    streams: list[list[Frame]]

    @property
    def frames(self) -> int:
        return sum(len(s) for s in self.streams)

    def boxes_per_frame(self) -> dict[str, float]:
        n = np.array([len(f.boxes) for s in self.streams for f in s], dtype=np.float64)
        if n.size == 0:
            return {"mean": 0.0, "max": 0.0}
        return {"mean": round(float(n.mean()), 1), "max": float(n.max())}


# ----------------------------------------------------------------------------- loads
def nuscenes_load(data: Path, scenes: int) -> Load:
    """The first ``scenes`` val scenes, all 7 tracked classes of the ``nuscenes`` preset in one
    tracker per scene (barrier, traffic cone, construction vehicle dropped)."""
    config = preset("nuscenes")
    files = list(scene_files(data / "nuscenes" / "centerpoint_val"))[:scenes]
    streams = [
        [
            Frame(boxes=f.boxes, stamp=f.stamp, pose=None, key_frame=True)
            for f in read_scene(p, config.class_names)
        ]
        for p in files
    ]
    return Load("nuscenes", config, config.class_names, streams)


def parity_load(load: Load) -> Load:
    """The same streams with the two settings that reproduce the reference's output exactly
    (its vertical-overlap formula, its NMS tie order; tests/test_nuscenes_parity.py): the
    speed-up against the reference is only meaningful for the same output."""
    config = load.config.with_overrides(
        vertical_overlap=VerticalOverlap.REFERENCE, tie_order=TieOrder.REFERENCE
    )
    return Load(f"{load.name}_parity", config, load.classes, load.streams)


def kitti_load(data: Path, classes: Sequence[str], sequences: int) -> Load:
    """The first ``sequences`` train sequences, ``classes`` in one tracker per sequence."""
    config = preset("kitti")
    streams = []
    for seq in TRAIN_SEQUENCES[:sequences]:
        frames = load_sequence(data / "kitti", seq, config, classes)
        streams.append([Frame(boxes=f.boxes, stamp=f.stamp, pose=None) for f in frames])
    name = "kitti_" + ("all" if len(classes) > 1 else classes[0].lower())
    return Load(name, config, tuple(classes), streams)


def synthetic_stream(n: int, frames: int, seed: int = 0) -> list[Frame]:
    """``n`` cars on a 12 m grid driving one way at ~5 m/s with small speed differences and
    measurement noise: they never overlap (NMS keeps all ``n``) and each frame matches every
    track, so the tracker holds ``n`` tracks from the second frame on."""
    rng = np.random.default_rng(seed)
    side = math.ceil(math.sqrt(n))
    gx, gy = np.divmod(np.arange(n), side)
    start = np.stack([gx * 12.0, gy * 12.0], axis=1)
    velocity = np.column_stack([5.0 + rng.uniform(-0.2, 0.2, n), rng.uniform(-0.1, 0.1, n)])
    size = np.column_stack(
        [rng.uniform(4.2, 4.8, n), rng.uniform(1.8, 2.0, n), rng.uniform(1.5, 1.8, n)]
    )
    score = rng.uniform(0.3, 0.95, n)
    out = []
    for k in range(frames):
        t = k * SYNTHETIC_PERIOD_S
        xy = start + velocity * t + rng.normal(0.0, 0.1, (n, 2))
        params = np.column_stack([xy, np.full(n, 0.9), rng.normal(0.0, 0.02, n), size])
        boxes = Boxes.from_arrays(params, score, np.zeros(n, np.int32))
        out.append(Frame(boxes=boxes, stamp=t, pose=None))
    return out


# ----------------------------------------------------------------------------- timing
def time_streams(
    config: TrackerConfig,
    streams: Sequence[Sequence[Frame]],
    skip: int = 0,
    budget_s: float = math.inf,
) -> list[float]:
    """Seconds per ``Tracker.step`` (a fresh tracker per stream); the first ``skip`` frames of
    each stream are stepped but not timed (the sweep's ramp-up to ``n`` tracks). Stops early,
    after at least ``MIN_TIMED`` frames, once the timed steps exceed ``budget_s``."""
    clock = time.perf_counter_ns
    out: list[float] = []
    spent = 0.0
    for frames in streams:
        tracker = Tracker(config)
        for k, frame in enumerate(frames):
            t0 = clock()
            tracker.step(frame)
            dt = (clock() - t0) * 1e-9
            if k >= skip:
                out.append(dt)
                spent += dt
                if spent > budget_s and len(out) >= MIN_TIMED:
                    return out
    return out


def stage_breakdown(
    config: TrackerConfig,
    streams: Sequence[Sequence[Frame]],
    skip: int = 0,
    frames_max: int | None = None,
) -> dict[str, Any]:
    """Seconds and calls per stage over the timed frames (at most ``frames_max`` per stream),
    with the shims installed."""
    clock = time.perf_counter_ns
    timed_total = 0.0
    cap = None if frames_max is None else skip + frames_max
    with StageTimer() as timer:
        for frames in streams:
            tracker = Tracker(config)
            for k, frame in enumerate(frames[:cap]):
                if k < skip:  # ramp-up frame: stepped, then its stage time is rolled back
                    before = (dict(timer.seconds), dict(timer.calls))
                    tracker.step(frame)
                    timer.seconds, timer.calls = before
                    continue
                t0 = clock()
                tracker.step(frame)
                timed_total += (clock() - t0) * 1e-9
    timed = sum(max(len(s[:cap]) - skip, 0) for s in streams)
    seconds = dict(timer.seconds)
    seconds[OTHER] = max(timed_total - sum(seconds.values()), 0.0)
    share = {k: (v / timed_total if timed_total > 0 else 0.0) for k, v in seconds.items()}
    return {
        "frames": timed,
        "shimmed_total_s": round(timed_total, 4),
        "ms_per_frame": {k: round(1e3 * v / max(timed, 1), 4) for k, v in seconds.items()},
        "share": {k: round(v, 4) for k, v in share.items()},
        "calls": dict(timer.calls),
    }


def warm_up(config: TrackerConfig, frames: Sequence[Frame]) -> None:
    """First calls pay for lazy imports and allocator growth: not what a frame costs."""
    tracker = Tracker(config)
    for f in frames[:5]:
        tracker.step(f)


def bench_load(load: Load) -> dict[str, Any]:
    if load.streams and load.streams[0]:
        warm_up(load.config, load.streams[0])
    lat = time_streams(load.config, load.streams)
    total = float(sum(lat))
    return {
        "preset": load.name.split("_")[0],
        "classes": list(load.classes),
        "streams": len(load.streams),
        "frames": len(lat),
        "boxes_per_frame": load.boxes_per_frame(),
        "frames_per_s": round(len(lat) / total, 2) if total > 0 else None,
        "latency": summary_ms(lat),
        "stages": stage_breakdown(load.config, load.streams),
    }


def sweep(
    sizes: Sequence[int], frames: int, budget_s: float = 5.0, ramp: int = 2
) -> dict[str, Any]:
    """Per-frame time against boxes per frame (= live tracks), one class (the worst case for
    the cost matrix: every box against every track). Each size gets ``frames`` timed frames,
    fewer (at least MIN_TIMED) when they take over ``budget_s``."""
    config = preset("nuscenes")
    warm_up(config, synthetic_stream(10, 5))
    points: list[dict[str, Any]] = []
    for n in sizes:
        stream = synthetic_stream(n, frames + ramp, seed=n)
        lat = time_streams(config, [stream], skip=ramp, budget_s=budget_s)
        points.append(
            {
                "boxes": n,
                "latency": summary_ms(lat),
                "stages": stage_breakdown(config, [stream], skip=ramp, frames_max=len(lat)),
            }
        )
    xs = [p["boxes"] for p in points]
    ys = [p["latency"]["p50_ms"] for p in points]
    k_all, c_all = power_law(xs, ys)
    tail = [(x, y) for x, y in zip(xs, ys, strict=True) if x >= TAIL_FROM]
    k_tail, c_tail = power_law(*zip(*tail, strict=True)) if len(tail) >= 2 else (math.nan, math.nan)
    return {
        "preset": "nuscenes",
        "classes": ["car"],
        "frames_per_size": frames,
        "points": points,
        "exponent": round(k_all, 3),
        "coefficient_ms": c_all,
        "exponent_from_100": None if math.isnan(k_tail) else round(k_tail, 3),
        "coefficient_from_100_ms": None if math.isnan(c_tail) else c_tail,
    }


def against_reference(results: dict[str, Any]) -> dict[str, Any]:
    out: dict[str, Any] = {"source": REFERENCE_SOURCE, "goal_speedup": GOAL_SPEEDUP}
    for name in ("nuscenes", "nuscenes_parity"):
        nu = results.get(name)
        if nu and nu["latency"]["count"]:
            lat = nu["latency"]
            ratio = REFERENCE_NUSCENES["p50_ms"] / lat["p50_ms"]
            out[name] = {
                "reference": REFERENCE_NUSCENES,
                "median_speedup": round(ratio, 1),
                "p99_speedup": round(REFERENCE_NUSCENES["p99_ms"] / lat["p99_ms"], 1),
                "frames_per_s_speedup": round(
                    nu["frames_per_s"] / REFERENCE_NUSCENES["frames_per_s"], 1
                ),
                "meets_goal": ratio >= GOAL_SPEEDUP,
            }
    car = results.get("kitti_car")
    if car and car["latency"]["count"]:
        out["kitti_car"] = {
            "reference": REFERENCE_KITTI_CAR,
            "median_speedup": round(REFERENCE_KITTI_CAR["p50_ms"] / car["latency"]["p50_ms"], 1),
            "p99_speedup": round(REFERENCE_KITTI_CAR["p99_ms"] / car["latency"]["p99_ms"], 1),
            "frames_per_s_speedup": round(
                car["frames_per_s"] / REFERENCE_KITTI_CAR["frames_per_s"], 1
            ),
        }
    every = results.get("kitti_all")
    if every and every["latency"]["count"]:
        # The reference runs one tracker per class: its time per frame is the sum.
        ref_fps = 1.0 / sum(1.0 / v for v in REFERENCE_KITTI_FPS.values())
        out["kitti_all"] = {
            "reference": {"frames_per_s": round(ref_fps, 1), "derived_from": REFERENCE_KITTI_FPS},
            "frames_per_s_speedup": round(every["frames_per_s"] / ref_fps, 1),
        }
    return out


@dataclass(frozen=True, slots=True)
class CoreOptions:
    data: Path
    scenes: int
    kitti_sequences: int
    sizes: tuple[int, ...]
    sweep_frames: int
    sweep_budget_s: float = 5.0
    # Cross-validation candidates (eval/cv.py) whose cost each real load is timed with too:
    # the load again with the candidate's changes in every class, named "<load>+<name>".
    options: tuple[str, ...] = ()


def _with_options(
    load: Load, options: Sequence[str], progress: Callable[[str], None]
) -> dict[str, Any]:
    known = {c.name: c for c in ALL_CANDIDATES}
    out = {}
    for name in options:
        progress(f"{load.name} with {name} ...")
        config = known[name].in_every_class(load.config)
        out[f"{load.name}+{name}"] = bench_load(Load(load.name, config, load.classes, load.streams))
    return out


def run_core(opts: CoreOptions, progress: Callable[[str], None] = print) -> dict[str, Any]:
    resolve_targets()  # a stage the core renamed fails now, not after the loads are read
    # One-off start-up costs (scipy's lazily imported solvers, the kernels' compile or cache
    # load) are paid before anything is timed, as the service pays them before its first
    # frame; warm_up() would hide most of it, but only for what its five frames reach.
    solvers.preload()
    jit.preload()
    results: dict[str, Any] = {}
    fused: dict[str, Any] | None = None
    if opts.scenes > 0:
        progress(f"nuScenes: loading {opts.scenes} scenes from {opts.data / 'nuscenes'} ...")
        load = nuscenes_load(opts.data, opts.scenes)
        results["nuscenes"] = bench_load(load)
        results.update(_with_options(load, opts.options, progress))
        progress("nuScenes again, configured for parity with the reference ...")
        results["nuscenes_parity"] = bench_load(parity_load(load))
        progress("nuScenes as a fused vehicle: the lidar and a front camera ...")
        fused = bench_fused(load.config, load.streams)
    if opts.kitti_sequences > 0:
        for classes in (("Car",), KITTI_CLASSES):
            load = kitti_load(opts.data, classes, opts.kitti_sequences)
            progress(f"KITTI {'+'.join(classes)}: {load.frames} frames ...")
            results[load.name] = bench_load(load)
            results.update(_with_options(load, opts.options, progress))
    sw = None
    if opts.sizes:
        progress(f"scaling sweep: {', '.join(map(str, opts.sizes))} boxes ...")
        sw = sweep(opts.sizes, opts.sweep_frames, opts.sweep_budget_s)
    return {
        "loads": results,
        "fused": fused,
        "reference": against_reference(results),
        "sweep": sw,
    }
