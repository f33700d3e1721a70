"""``simpletrack track nuscenes``: track detection files offline and write JSON lines."""

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
from simpletrack.eval.parity import compare, group_rows
from simpletrack.eval.track_nuscenes import track_scene

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
