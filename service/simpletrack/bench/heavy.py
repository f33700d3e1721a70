"""What one heavy frame costs: time and peak memory of ``Tracker.step`` on a synthetic street
scene of N boxes (7 nuScenes classes, 200 m x 200 m, a third of them in crowds) against the
tracks the previous frame of the same scene left, the way a real sensor's frame arrives.

    python -m simpletrack.bench.heavy 1000 3000 10000     # one subprocess per size

Peak memory is tracemalloc's (NumPy reports its buffers to it) over the timed step alone;
each size runs in a fresh interpreter so one size's allocator state never leaks into the next,
and the subprocess's maximum resident set (``ru_maxrss``) is reported next to it.
"""

from __future__ import annotations

import json
import resource
import subprocess
import sys
import time
import tracemalloc
from dataclasses import dataclass
from typing import Any

import numpy as np

from simpletrack.core import jit, solvers
from simpletrack.core.boxes import Boxes
from simpletrack.core.config import preset
from simpletrack.core.frames import Frame
from simpletrack.core.tracker import Tracker

AREA_M = 200.0
CROWD_SHARE = 1 / 3
CROWDS = 12
CROWD_SIGMA_M = 6.0
PERIOD_S = 0.5
# (nuScenes preset class, share of boxes, l, w, h in metres).
MIX: tuple[tuple[str, float, float, float, float], ...] = (
    ("car", 0.45, 4.6, 1.9, 1.7),
    ("pedestrian", 0.30, 0.7, 0.7, 1.75),
    ("truck", 0.07, 7.0, 2.4, 3.0),
    ("bus", 0.03, 11.0, 2.9, 3.4),
    ("trailer", 0.03, 10.0, 2.6, 3.8),
    ("bicycle", 0.06, 1.7, 0.6, 1.3),
    ("motorcycle", 0.06, 2.1, 0.8, 1.5),
)


@dataclass(frozen=True, slots=True)
class Scene:
    """Two consecutive frames of one scene: the first makes the tracks, the second is timed."""

    first: Frame
    second: Frame


def heavy_scene(n: int, seed: int = 0) -> Scene:
    """``n`` boxes, uniform over the area except ``CROWD_SHARE`` of them in Gaussian crowds;
    the second frame moves every box by its own velocity (0-10 m/s) plus 0.1 m noise."""
    rng = np.random.default_rng(seed)
    names = preset("nuscenes").class_names
    share = np.array([m[1] for m in MIX])
    kind = rng.choice(len(MIX), size=n, p=share / share.sum())
    size = np.array([m[2:] for m in MIX])[kind] * rng.uniform(0.9, 1.1, (n, 3))
    xy = rng.uniform(-AREA_M / 2, AREA_M / 2, (n, 2))
    crowd = rng.random(n) < CROWD_SHARE
    centres = rng.uniform(-AREA_M / 2, AREA_M / 2, (CROWDS, 2))
    xy[crowd] = centres[rng.integers(0, CROWDS, int(crowd.sum()))]
    xy[crowd] += rng.normal(0.0, CROWD_SIGMA_M, (int(crowd.sum()), 2))
    yaw = rng.uniform(-np.pi, np.pi, n)
    speed = rng.uniform(0.0, 10.0, n)
    velocity = np.column_stack([np.cos(yaw), np.sin(yaw)]) * speed[:, None]
    cls = np.array([names.index(MIX[k][0]) for k in kind], dtype=np.int32)
    score = rng.uniform(0.05, 0.95, n)

    def frame(k: int) -> Frame:
        moved = xy + velocity * (k * PERIOD_S) + rng.normal(0.0, 0.1, (n, 2)) * k
        z = size[:, 2] / 2 + rng.normal(0.0, 0.05, n)
        params = np.column_stack([moved, z, yaw + rng.normal(0.0, 0.02, n) * k, size])
        return Frame(boxes=Boxes.from_arrays(params, score, cls), stamp=k * PERIOD_S)

    return Scene(first=frame(0), second=frame(1))


def measure(n: int, seed: int = 0) -> dict[str, Any]:
    """Seconds and tracemalloc peak (MB) of the second frame's step (preset nuscenes)."""
    # scipy's solvers are imported on first call and the kernels compiled (or loaded) on
    # first call: a one-off start-up cost, not what a heavy frame costs, so paid here.
    solvers.preload()
    jit.preload()
    scene = heavy_scene(n, seed)
    config = preset("nuscenes")
    timed = Tracker(config)
    timed.step(scene.first)
    tracks = len(timed.tracks)  # live before the timed frame
    t0 = time.perf_counter()
    timed.step(scene.second)
    seconds = time.perf_counter() - t0
    traced = Tracker(config)
    traced.step(scene.first)
    tracemalloc.start()
    traced.step(scene.second)
    peak = tracemalloc.get_traced_memory()[1]
    tracemalloc.stop()
    return {
        "boxes": n,
        "tracks": tracks,
        "step_s": round(seconds, 4),
        "peak_mb": round(peak / 2**20, 1),
        "max_rss_mb": round(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024, 1),
    }


def main(argv: list[str]) -> int:
    if len(argv) == 1:
        print(json.dumps(measure(int(argv[0]))))
        return 0
    for size in argv or ["1000", "3000", "10000"]:
        subprocess.run([sys.executable, "-m", "simpletrack.bench.heavy", size], check=True)
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
