"""nuScenes CenterPoint detection files → tracker frames.

The files use the KITTI detection columns (camera frame, bottom centre, y down), so the same
conversion to the tracker's z-up frame applies (simpletrack.datasets.kitti.camera_to_tracker)."""

from __future__ import annotations

from collections.abc import Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from simpletrack.core.boxes import Boxes
from simpletrack.datasets.kitti import camera_to_tracker

# Column `type` of the files → nuScenes class name (barrier and cone are not tracked).
TYPE_NAMES = {
    1: "pedestrian",
    2: "car",
    3: "bicycle",
    4: "motorcycle",
    5: "bus",
    6: "trailer",
    7: "truck",
    8: "construction_vehicle",
    9: "barrier",
    10: "traffic_cone",
}
FRAME_PERIOD_S = 0.5


@dataclass(frozen=True, slots=True)
class SceneFrame:
    index: int
    stamp: float
    boxes: Boxes  # class codes index the given class list


def read_scene(path: Path, classes: Sequence[str]) -> list[SceneFrame]:
    """All frames of one scene file, keeping only boxes of ``classes`` (codes = positions)."""
    raw = np.loadtxt(path, delimiter=",", ndmin=2)
    code_of_type = np.full(max(TYPE_NAMES) + 1, -1, dtype=np.int32)
    for t, name in TYPE_NAMES.items():
        if name in classes:
            code_of_type[t] = classes.index(name)
    frame = raw[:, 0].astype(np.int64)
    cls = code_of_type[raw[:, 1].astype(np.int64)]
    keep = cls >= 0
    params = camera_to_tracker(raw[:, 7:14])
    n_frames = int(frame.max()) + 1 if raw.size else 0
    out = []
    for k in range(n_frames):
        rows = np.flatnonzero((frame == k) & keep)
        out.append(
            SceneFrame(
                index=k,
                stamp=k * FRAME_PERIOD_S,
                boxes=Boxes(params=params[rows], score=raw[rows, 6].copy(), cls=cls[rows]),
            )
        )
    return out


def scene_files(data: Path, scenes: Sequence[str] | None = None) -> Iterator[Path]:
    """Scene files of ``data`` in name order (all, or the named ones)."""
    if scenes:
        for name in scenes:
            path = data / f"{name}.txt"
            if not path.is_file():
                raise FileNotFoundError(f"no detection file for {name} in {data}")
            yield path
    else:
        yield from sorted(data.glob("scene-*.txt"))
