"""``simpletrack track nuscenes``: track detection files offline and write JSON lines, or a
nuScenes detection-results JSON into a nuScenes tracking submission (docs/NUSCENES.md)."""

from __future__ import annotations

import argparse
import gzip
import json
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

from simpletrack.cli.errors import UserError
from simpletrack.core.config import TieOrder, VerticalOverlap, preset
from simpletrack.datasets.nuscenes import scene_files
from simpletrack.datasets.nuscenes_json import (
    FormatError,
    check_tracking_classes,
    read_detections,
    read_samples,
    scenes_to_track,
    track_scenes,
    write_submission,
)
from simpletrack.datasets.paths import NUSCENES, MissingData, data_dir, default_help
from simpletrack.eval.parity import compare, group_rows
from simpletrack.eval.track_nuscenes import track_scene

EPILOG = """\
The detection files are --data, else $SIMPLETRACK_DATA/nuscenes/centerpoint_val
(SIMPLETRACK_DATA: the folder holding the datasets); there is no default folder.

examples:
  simpletrack track nuscenes --data ../shared/data/nuscenes/centerpoint_val --out out/nusc.jsonl
  simpletrack track nuscenes --data ../shared/data/nuscenes/centerpoint_val \\
      --scenes scene-0003,scene-0012 --vertical-overlap reference \\
      --reference ../shared/data/reference/nuscenes/simpletrack_nuscenes_val.jsonl.gz
  simpletrack track nuscenes --detections results_val.json \\
      --samples /data/nuscenes/v1.0-trainval --out out/tracking_val.json
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
    p.add_argument(
        "--data",
        type=Path,
        metavar="FOLDER",
        help=f"nuScenes detection files, scene-*.txt ({default_help(NUSCENES)})",
    )
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
    p.add_argument(
        "--detections",
        type=Path,
        help="a nuScenes detection-results JSON to track instead of --data (needs --samples; "
        "--out is then a nuScenes tracking-submission JSON; docs/NUSCENES.md)",
    )
    p.add_argument(
        "--samples",
        type=Path,
        help="with --detections: nuScenes' sample table (sample.json, or its folder such as "
        "<dataroot>/v1.0-trainval), which gives each sample's scene and timestamp",
    )
    p.add_argument(
        "--out",
        type=Path,
        help="JSON lines output (one line per output box); with --detections the submission",
    )
    p.add_argument(
        "--reference", type=Path, help="reference JSON lines (.gz ok): print parity against it"
    )
    p.set_defaults(func=run)


def _read_jsonl(path: Path, scenes: set[str]) -> Iterator[dict[str, Any]]:
    opener = gzip.open if path.suffix == ".gz" else open
    with opener(path, "rt") as f:
        for line in f:
            row = json.loads(line)
            if row["scene"] in scenes:
                yield row


def run(args: argparse.Namespace) -> int:
    if args.detections is not None:
        return _run_detections(args)
    if args.samples is not None:
        raise UserError("--samples goes with --detections")
    try:
        args.data = data_dir(args.data, NUSCENES)
    except MissingData as exc:
        raise UserError(str(exc)) from None
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


def _run_detections(args: argparse.Namespace) -> int:
    """nuScenes detection results in, a nuScenes tracking submission out."""
    if args.samples is None:
        raise UserError(
            "--detections needs --samples: nuScenes' sample table (sample.json, or its folder "
            "such as <dataroot>/v1.0-trainval), which gives each sample's scene and timestamp "
            "(a results JSON has neither)"
        )
    if args.out is None:
        raise UserError("--detections needs --out (the tracking submission JSON to write)")
    if args.reference is not None:
        raise UserError(
            "--reference compares JSON lines from --data; it does not go with --detections"
        )
    try:
        config = preset(args.preset).with_overrides(
            vertical_overlap=args.vertical_overlap, tie_order=args.tie_order
        )
        check_tracking_classes(config)
        table = read_samples(args.samples)
        detections = read_detections(args.detections)
        scenes = scenes_to_track(detections, table, [s for s in args.scenes.split(",") if s])
    except (FormatError, ValueError) as exc:
        raise UserError(str(exc)) from None
    if not scenes:
        raise UserError(f"--detections {args.detections} has no samples")
    args.out.parent.mkdir(parents=True, exist_ok=True)
    t0 = time.perf_counter()
    tmp = args.out.with_name(args.out.name + ".partial")
    try:
        with tmp.open("w") as f:
            n_samples, n_boxes, dropped = write_submission(
                f, detections.meta, track_scenes(detections, scenes, config)
            )
        tmp.replace(args.out)
    except FormatError as exc:
        tmp.unlink(missing_ok=True)
        raise UserError(str(exc)) from None
    except OSError as exc:
        tmp.unlink(missing_ok=True)
        raise UserError(f"--out {args.out}: {exc.strerror or exc}") from None
    total = time.perf_counter() - t0
    print(
        f"tracked {len(scenes)} scenes, {n_samples} samples, {n_boxes} output boxes in "
        f"{total:.1f} s ({n_samples / total if total else 0:.0f} samples/s)"
    )
    if dropped:
        print(f"left out {dropped} lowest-scored boxes over 500 in a sample (the format's limit)")
    print(f"wrote {args.out} (nuScenes tracking submission)")
    return 0
