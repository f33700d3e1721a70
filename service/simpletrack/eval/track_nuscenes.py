"""Offline tracking of nuScenes detection files into the reference's JSON rows
(``simpletrack track nuscenes``, the parity check, ``python -m simpletrack.eval.track_nuscenes``
to time one tracker against one per class)."""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np

from simpletrack.core.config import TrackerConfig
from simpletrack.core.frames import Frame, Tracks
from simpletrack.core.tracker import Tracker
from simpletrack.datasets.nuscenes import read_scene
from simpletrack.wire.convert import wire_states
from simpletrack.wire.reasons import STATE_NAMES


def track_scene(
    path: Path, config: TrackerConfig, *, per_class: bool = False
) -> Iterator[dict[str, Any]]:
    """The reference's output: ids per scene and class from 0. Classes never interact in the
    tracker (class-aware NMS, same-class pairs only, per-class life cycles), so one tracker
    for all classes gives the per-class trackers' tracks, in the same order within a class;
    its ids are numbered per class in the order of birth, as the per-class trackers number
    them (tests/eval/test_track_nuscenes.py proves the rows equal). ``per_class`` runs one
    tracker per class, as the reference does (a third of the speed)."""
    scene = path.stem
    names = list(config.class_names)
    frames = read_scene(path, names)
    if per_class:
        trackers = [Tracker(config) for _ in names]
        for fr in frames:
            for code, tracker in enumerate(trackers):
                only = Frame(boxes=fr.boxes.take(fr.boxes.cls == code), stamp=fr.stamp)
                tracks = tracker.step(only)
                order = list(range(len(tracks)))
                yield from _rows(scene, fr.index, names, tracks, order, tracks.ids.tolist())
        return
    tracker = Tracker(config)
    local: list[dict[int, int]] = [{} for _ in names]  # per class: tracker id -> class id
    for fr in frames:
        tracks = tracker.step(Frame(boxes=fr.boxes, stamp=fr.stamp))
        order = np.argsort(tracks.boxes.cls, kind="stable").tolist()
        codes, raw = tracks.boxes.cls.tolist(), tracks.ids.tolist()
        ids = [local[codes[i]].setdefault(raw[i], len(local[codes[i]])) for i in order]
        yield from _rows(scene, fr.index, names, tracks, order, ids)


def _rows(
    scene: str, frame: int, names: list[str], tracks: Tracks, order: list[int], ids: list[int]
) -> Iterator[dict[str, Any]]:
    """The rows of ``tracks`` in ``order``, the k-th with id ``ids[k]``."""
    box = tracks.boxes.params
    states = wire_states(tracks).tolist()
    codes = tracks.boxes.cls.tolist()
    for k, i in enumerate(order):
        b = box[i]
        yield {
            "scene": scene,
            "frame": frame,
            "cls": names[codes[i]],
            "id": ids[k],
            "box": [round(float(v), 2) for v in b[:3]]
            + [round(float(b[3]), 4)]
            + [round(float(v), 2) for v in b[4:]],
            "score": round(float(tracks.boxes.score[i]), 4),
            "state": STATE_NAMES[states[i]],
        }


def main() -> None:
    """Time ``track_scene`` both ways on the first N val scenes, alternating, medians of 3."""
    import argparse
    import statistics
    import time

    from simpletrack.core.config import preset
    from simpletrack.datasets.paths import NUSCENES, MissingData, data_dir, default_help

    p = argparse.ArgumentParser(
        prog="python -m simpletrack.eval.track_nuscenes", description=main.__doc__
    )
    p.add_argument(
        "--data",
        type=Path,
        metavar="FOLDER",
        help=f"nuScenes detection files, scene-*.txt ({default_help(NUSCENES)})",
    )
    p.add_argument("--scenes", type=int, default=10)
    p.add_argument("--runs", type=int, default=3)
    args = p.parse_args()
    try:
        args.data = data_dir(args.data, NUSCENES)
    except MissingData as exc:
        p.exit(2, f"{p.prog}: error: {exc}\n")
    scenes = sorted(args.data.glob("scene-*.txt"))[: args.scenes]
    config = preset("nuscenes")
    times: dict[bool, list[float]] = {False: [], True: []}
    for _ in range(args.runs):
        for per_class in (False, True):
            t0 = time.perf_counter()
            for path in scenes:
                for _row in track_scene(path, config, per_class=per_class):
                    pass
            times[per_class].append(time.perf_counter() - t0)
    one, per = statistics.median(times[False]), statistics.median(times[True])
    print(
        f"{len(scenes)} scenes, medians of {args.runs}: one tracker {one:.2f} s, one per class "
        f"{per:.2f} s ({per / one:.1f}x)"
    )


if __name__ == "__main__":
    main()
