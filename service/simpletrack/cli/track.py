"""``simpletrack track nuscenes``: track detection files offline and write JSON lines."""

from __future__ import annotations

import argparse
import gzip
import json
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np

from simpletrack.cli.errors import UserError
from simpletrack.core.config import TieOrder, TrackerConfig, VerticalOverlap, preset
from simpletrack.core.frames import Frame, Tracks
from simpletrack.core.tracker import Tracker
from simpletrack.datasets.nuscenes import read_scene, scene_files
from simpletrack.eval.parity import compare, group_rows
from simpletrack.wire.convert import wire_states
from simpletrack.wire.reasons import WireTrackState

EPILOG = """examples:
  simpletrack track nuscenes --data ../shared/data/nuscenes/centerpoint_val --out out/nusc.jsonl
  simpletrack track nuscenes --scenes scene-0003,scene-0012 --vertical-overlap reference \\
      --reference ../shared/data/reference/nuscenes/simpletrack_nuscenes_val.jsonl.gz
"""


def register(sub: Any) -> None:
    p = sub.add_parser(
        "track",
        help="track detection files offline (nuScenes)",
        description="Track detection files offline with the core tracker and write JSON lines.",
        epilog=EPILOG,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument("dataset", choices=["nuscenes"], help="layout of the detection files")
    p.add_argument("--data", type=Path, default=Path("../shared/data/nuscenes/centerpoint_val"))
    p.add_argument("--scenes", default="", help="comma-separated scene names (default: all)")
    p.add_argument("--preset", default="nuscenes")
    p.add_argument(
        "--vertical-overlap", choices=[v.value for v in VerticalOverlap], default="exact"
    )
    p.add_argument(
        "--tie-order",
        choices=[v.value for v in TieOrder],
        default="stable",
        help="order of equal-score boxes in NMS (reference: the reference code's NumPy order)",
    )
    p.add_argument("--out", type=Path, help="JSON lines output (one line per output box)")
    p.add_argument(
        "--reference", type=Path, help="reference JSON lines (.gz ok): print parity against it"
    )
    p.set_defaults(func=run)


STATE_NAMES = {int(s): s.name.lower() for s in WireTrackState}


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


def _read_jsonl(path: Path, scenes: set[str]) -> Iterator[dict[str, Any]]:
    opener = gzip.open if path.suffix == ".gz" else open
    with opener(path, "rt") as f:
        for line in f:
            row = json.loads(line)
            if row["scene"] in scenes:
                yield row


def run(args: argparse.Namespace) -> int:
    if not args.data.is_dir():
        raise UserError(f"--data {args.data} is not a directory")
    try:
        config = preset(args.preset).with_overrides(
            vertical_overlap=args.vertical_overlap, tie_order=args.tie_order
        )
        files = list(scene_files(args.data, [s for s in args.scenes.split(",") if s]))
    except (ValueError, FileNotFoundError) as exc:
        raise UserError(str(exc)) from None
    if not files:
        raise UserError(f"no scene-*.txt files in {args.data}")
    if args.reference and not args.reference.is_file():
        raise UserError(f"--reference {args.reference} does not exist")
    rows: list[dict[str, Any]] = []
    per_frame: list[float] = []
    n_frames = 0
    for path in files:
        t0 = time.perf_counter()
        scene_rows = list(track_scene(path, config))
        per_frame.append(time.perf_counter() - t0)
        n_frames += 1 + max((r["frame"] for r in scene_rows), default=-1)
        rows.extend(scene_rows)
    total = sum(per_frame)
    print(
        f"tracked {len(files)} scenes, {n_frames} frames, {len(rows)} output boxes in "
        f"{total:.1f} s ({n_frames / total if total else 0:.0f} frames/s)"
    )
    if args.out:
        args.out.parent.mkdir(parents=True, exist_ok=True)
        with args.out.open("w") as f:
            for r in rows:
                f.write(json.dumps(r, separators=(",", ":")) + "\n")
        print(f"wrote {args.out}")
    if args.reference:
        ref = group_rows(_read_jsonl(args.reference, {p.stem for p in files}))
        report = compare(ref, group_rows(rows))
        print(json.dumps(report.as_dict(), indent=1))
    return 0
