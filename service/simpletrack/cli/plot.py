"""``simpletrack plot``: bird's-eye-view pictures of recorded tracks."""

from __future__ import annotations

import argparse
import re
import sys
from pathlib import Path

from simpletrack.cli.errors import UserError

EPILOG = """\
what --out makes (override with --kind):
  NAME.png          one overview: every track's trajectory in its own colour
  NAME.gif / .mp4   an animation of the frames (MP4 needs ffmpeg)
  DIR               one PNG per frame: DIR/frame_000000.png, ...

examples:
  # trajectories of a recorded stream, with ground truth
  simpletrack plot out/tracks.jsonl --stream veh00/lidar --truth out/truth.jsonl --out overview.png

  # KITTI results against labels and detections, frames 0-99 as PNGs
  simpletrack plot results/data_0/0000.txt --truth ../shared/data/kitti/labels/0000.txt \\
      --detections ../shared/data/kitti/detections/pointrcnn/Car/0000.txt \\
      --frames 0:100 --out plots/0000/

  # an animated GIF at 10 frames per second
  simpletrack plot results/data_0/0000.txt --frames 0:80 --out 0000.gif --fps 10

Track files: JSON lines from `simpletrack record --format jsonl` (one frame per line) or with
one box per line; KITTI tracking results or labels; KITTI-style detection CSV files.
"""


def register(subparsers: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    p = subparsers.add_parser(
        "plot",
        help="bird's-eye-view PNGs, trajectory overviews and animations of recorded tracks",
        description="Draw recorded tracks from above, each track id in its own colour, with "
        "optional ground truth (dashed) and detections (grey).",
        formatter_class=argparse.RawDescriptionHelpFormatter,
        epilog=EPILOG,
    )
    p.add_argument("tracks", type=Path, help="recorded tracks (JSON lines or KITTI format)")
    p.add_argument("--out", type=Path, required=True, help="NAME.png, NAME.gif, NAME.mp4 or DIR")
    p.add_argument(
        "--kind",
        choices=("overview", "frames", "animation"),
        help="what to draw (default: from --out's suffix)",
    )
    p.add_argument(
        "--format",
        choices=("auto", "jsonl", "kitti", "kitti-detections"),
        default="auto",
        help="format of TRACKS and --truth (default: auto-detected)",
    )
    p.add_argument("--stream", metavar="VEHICLE/SENSOR", help="which stream of a JSON-lines file")
    p.add_argument("--truth", type=Path, help="ground truth (KITTI labels or JSON lines)")
    p.add_argument(
        "--detections",
        type=Path,
        action="append",
        default=[],
        help="detections to draw (repeatable: e.g. one KITTI file per class)",
    )
    p.add_argument("--classes", help="only these classes, comma separated (case-insensitive)")
    p.add_argument("--frames", help="START:END (END exclusive) or a comma-separated list")
    p.add_argument(
        "--size", default="900x900", help="picture size in pixels, WxH (default 900x900)"
    )
    p.add_argument("--fps", type=float, default=10.0, help="animation frame rate (default 10)")
    p.add_argument("--tail", type=int, default=15, help="trajectory frames behind each track")
    p.add_argument("--no-labels", action="store_true", help="do not write track ids")
    p.add_argument("--title", default="", help="title prefix (default: the tracks file name)")
    p.set_defaults(func=run)


def parse_size(text: str) -> tuple[int, int]:
    m = re.fullmatch(r"(\d+)x(\d+)", text.strip())
    if not m or not (100 <= int(m[1]) <= 8000 and 100 <= int(m[2]) <= 8000):
        raise UserError(f"--size {text!r} must be WxH in pixels, each 100..8000, e.g. 900x900")
    return int(m[1]), int(m[2])


def parse_frames(text: str | None, available: list[int]) -> list[int]:
    if text is None:
        return available
    try:
        if ":" in text:
            start_s, _, end_s = text.partition(":")
            start = int(start_s) if start_s else min(available, default=0)
            end = int(end_s) if end_s else max(available, default=-1) + 1
            wanted = set(range(start, end))
        else:
            wanted = {int(v) for v in text.split(",") if v.strip()}
    except ValueError:
        raise UserError(f"--frames {text!r} must be START:END or a list like 0,5,10") from None
    frames = sorted(wanted & set(available)) if available else sorted(wanted)
    if not frames:
        raise UserError(f"--frames {text!r} selects none of the recorded frames")
    return frames


def infer_kind(out: Path) -> str:
    suffix = out.suffix.lower()
    if suffix == ".png":
        return "overview"
    if suffix in (".gif", ".mp4"):
        return "animation"
    if suffix:
        raise UserError(f"--out {out}: use NAME.png, NAME.gif, NAME.mp4 or a directory")
    return "frames"


def run(args: argparse.Namespace) -> int:
    # Imported here: matplotlib is optional (the `plot` extra) and slow to import.
    try:
        from simpletrack import plot
        from simpletrack.datasets.track_files import (
            FileFormat,
            TrackFileError,
            merge,
            read_sequence,
        )
    except ImportError as exc:
        raise UserError(f"plotting needs matplotlib (pip install '.[plot]'): {exc}") from None

    width, height = parse_size(args.size)
    kind = args.kind or infer_kind(args.out)
    if kind == "animation" and args.out.suffix.lower() not in (".gif", ".mp4"):
        raise UserError(f"--out {args.out}: an animation is NAME.gif or NAME.mp4")
    if kind == "overview" and args.out.suffix.lower() != ".png":
        raise UserError(f"--out {args.out}: an overview is NAME.png")
    classes = {c.strip() for c in args.classes.split(",")} if args.classes else None
    fmt = FileFormat(args.format)
    try:
        tracks = {
            k: v.only(classes) for k, v in read_sequence(args.tracks, fmt, args.stream).items()
        }
        truth = None
        if args.truth is not None:
            truth_fmt = fmt if fmt is not FileFormat.KITTI_DETECTIONS else FileFormat.AUTO
            truth = {
                k: v.only(classes)
                for k, v in read_sequence(args.truth, truth_fmt, args.stream).items()
            }
        detections = None
        if args.detections:
            dets = merge([read_sequence(p, FileFormat.AUTO, args.stream) for p in args.detections])
            detections = {k: v.only(classes) for k, v in dets.items()}
    except TrackFileError as exc:
        raise UserError(str(exc)) from None
    if not tracks:
        raise UserError(f"{args.tracks}: no tracks to draw")

    frames = parse_frames(args.frames, sorted(tracks))
    style = plot.PlotStyle(
        width=width, height=height, tail=max(args.tail, 1), labels=not args.no_labels
    )
    title = args.title or args.tracks.name
    if kind == "overview":
        chosen = {k: tracks[k] for k in frames if k in tracks}
        chosen_truth = None if truth is None else {k: truth[k] for k in frames if k in truth}
        path = plot.save_overview(args.out, chosen, chosen_truth, style, title)
        print(f"wrote {path} ({len(frames)} frames)")
    elif kind == "animation":
        try:
            path = plot.save_animation(
                args.out, tracks, truth, detections, frames, style, args.fps, title
            )
        except RuntimeError as exc:
            raise UserError(str(exc)) from None
        print(f"wrote {path} ({len(frames)} frames at {args.fps:g} fps)")
    else:
        paths = plot.save_frames(args.out, tracks, truth, detections, frames, style, title)
        print(f"wrote {len(paths)} PNGs to {args.out}/")
    sys.stdout.flush()
    return 0
