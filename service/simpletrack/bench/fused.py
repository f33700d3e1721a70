"""A fused vehicle's step (core/vehicle.py) on nuScenes-sized frames: each val scene's
CenterPoint frames as a 360-degree lidar at 2 Hz, and a front camera (90 degrees, 70 m)
triggered with it (the same stamp: the scene's boxes in its view, moved by 0.3 m of noise;
the files carry no velocities to move them to another time), one VehicleTracker per scene. Each ``apply`` is timed;
beside it the same lidar frames through a one-sensor vehicle (the fusion wrapper's cost over
``Tracker.step``, which the ``nuscenes`` load times)."""

from __future__ import annotations

import time
from collections.abc import Sequence
from typing import Any

import numpy as np
import numpy.typing as npt

from simpletrack.bench.stats import summary_ms
from simpletrack.core.boxes import Boxes
from simpletrack.core.config import TrackerConfig
from simpletrack.core.frames import Frame
from simpletrack.core.fusion_config import FusionConfig, SensorTrust
from simpletrack.core.vehicle import SensorInput, VehicleTracker

T0_NS = 1_700_000_000_000_000_000
TWO = FusionConfig(
    sensors={
        "lidar": SensorTrust(),
        "camera": SensorTrust(fov_deg=90.0, max_range_m=70.0, verify=False, r=4.0),
    }
)
ONE = FusionConfig(sensors={"lidar": SensorTrust()})


def in_front_view(x: npt.NDArray[Any], y: npt.NDArray[Any]) -> npt.NDArray[np.bool_]:
    """Which points the benchmarks' front camera at the origin sees (90 degrees, 70 m: the
    camera of ``TWO`` and of the service benchmark's fusion settings)."""
    return np.asarray((np.hypot(x, y) <= 70.0) & (np.abs(np.arctan2(y, x)) <= np.pi / 4))


def camera_view(boxes: Boxes, rng: np.random.Generator) -> Boxes:
    """The boxes a front camera at the origin sees (``in_front_view``), 0.3 m off."""
    keep = in_front_view(boxes.params[:, 0], boxes.params[:, 1])
    seen = boxes.take(np.flatnonzero(keep))
    params = seen.params.copy()
    params[:, :2] += rng.normal(0.0, 0.3, (len(seen), 2))
    return Boxes(params=params, score=seen.score, cls=seen.cls)


def inputs(stream: Sequence[Frame], seed: int) -> list[SensorInput]:
    rng = np.random.default_rng(seed)
    out = []
    for k, f in enumerate(stream):
        stamp = T0_NS + round(f.stamp * 1e9)
        out.append(SensorInput("lidar", k, stamp, f.boxes))
        out.append(SensorInput("camera", k, stamp, camera_view(f.boxes, rng)))
    return out


def _time(config: TrackerConfig, fusion: FusionConfig, feed: Sequence[SensorInput]) -> list[float]:
    v = VehicleTracker(config, fusion)
    lat = []
    for inp in feed:
        t0 = time.perf_counter()
        v.apply(inp)
        lat.append(time.perf_counter() - t0)
    return lat


def bench_fused(config: TrackerConfig, streams: Sequence[Sequence[Frame]]) -> dict[str, Any]:
    feeds = [inputs(s, seed=i) for i, s in enumerate(streams)]
    if feeds and feeds[0]:
        _time(config, TWO, feeds[0][:10])  # first calls: lazy imports, allocator growth
    lidar: list[float] = []
    camera: list[float] = []
    one: list[float] = []
    for feed in feeds:
        lat = _time(config, TWO, feed)
        lidar += lat[0::2]
        camera += lat[1::2]
        one += _time(config, ONE, [f for f in feed if f.sensor == "lidar"])
    both = lidar + camera
    total = float(sum(both))
    n_cam = [len(f.boxes) for feed in feeds for f in feed if f.sensor == "camera"]
    return {
        "streams": len(feeds),
        "frames": len(both),
        "camera_boxes_per_frame": round(float(np.mean(n_cam)), 1) if n_cam else 0.0,
        "frames_per_s": round(len(both) / total, 2) if total > 0 else None,
        "latency": summary_ms(both),
        "lidar_latency": summary_ms(lidar),
        "camera_latency": summary_ms(camera),
        "one_sensor_latency": summary_ms(one),
    }


__all__ = ["bench_fused", "camera_view", "in_front_view", "inputs"]
