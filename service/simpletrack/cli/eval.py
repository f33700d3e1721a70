"""``simpletrack eval kitti``: track the KITTI sequences (or take existing result files) and
score them with AB3DMOT's KITTI 3D MOT evaluator (3D IoU 0.25), plus TrackEval's HOTA and IDF1
on the same boxes."""

from __future__ import annotations

import argparse
import json
import math
import time
from collections import Counter
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

from simpletrack.cli.errors import UserError
from simpletrack.core.config import TrackerConfig, preset
from simpletrack.core.frames import Frame, Tracks
from simpletrack.datasets.kitti import (
    KITTI_CLASSES,
    TRAIN_SEQUENCES,
    SequenceFrame,
    config_class_code,
    load_sequence,
    read_calib,
    result_class_names,
    write_tracked,
)
from simpletrack.datasets.paths import KITTI as KITTI_DATA
from simpletrack.datasets.paths import MissingData, data_dir, default_help
from simpletrack.eval.kitti import METRIC_NAMES, evaluate
from simpletrack.eval.tracking import track_sequence

EPILOG = """\
The KITTI folder is --data, else $SIMPLETRACK_DATA/kitti (SIMPLETRACK_DATA: the folder holding
the datasets); there is no default folder.

examples:
  export SIMPLETRACK_DATA=~/datasets   # holds kitti/ (or give --data ~/datasets/kitti each time)

  # track the 10 train sequences with the kitti preset, write OUT/data_0/*.txt, score them
  simpletrack eval kitti --results-dir out/kitti --json out/kitti/metrics.json

  # score existing result files only (e.g. the reference tracker's)
  simpletrack eval kitti --results "$SIMPLETRACK_DATA/reference/kitti_train/simpletrack/data_0"

  # two sequences, cars only, the KITTI folder given
  simpletrack eval kitti --data ../shared/data/kitti --seqs 0000,0002 --classes Car \\
      --results-dir out/kitti-car
"""

# Figures printed as counts rather than percentages.
COUNTS = ("IDS", "FRAG", "FP", "FN", "TP")
# Figures of the cross-validation table beside sAMOTA / MOTA / IDS.
CV_EXTRA = ("HOTA", "DetA", "AssA", "IDF1")


def register(sub: Any) -> None:
    p = sub.add_parser(
        "eval",
        help="evaluate tracking results (KITTI 3D MOT)",
        description="Evaluate tracking on a benchmark. Only KITTI for now.",
    )
    bench = p.add_subparsers(dest="benchmark", metavar="BENCHMARK", required=True)
    k = bench.add_parser(
        "kitti",
        help="track KITTI sequences and score them (sAMOTA, MOTA, IDS, HOTA, IDF1, ...)",
        description=(
            "Track KITTI tracking sequences with the core tracker (one tracker per sequence for "
            "all classes), write KITTI result files, and score them as AB3DMOT's evaluator "
            "does (3D IoU >= 0.25), with TrackEval's HOTA and IDF1 (3D IoU) beside its figures. "
            "With --results, score existing result files instead."
        ),
        epilog=EPILOG,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    k.add_argument(
        "--data",
        type=Path,
        metavar="FOLDER",
        help=f"KITTI folder with detections/pointrcnn, labels, calib ({default_help(KITTI_DATA)})",
    )
    k.add_argument(
        "--seqs",
        default=",".join(TRAIN_SEQUENCES),
        help="comma-separated sequences (default: the 10 train sequences)",
    )
    k.add_argument(
        "--classes",
        default=",".join(KITTI_CLASSES),
        help="comma-separated classes among Car,Pedestrian,Cyclist (default: all)",
    )
    k.add_argument("--preset", default="kitti", help="tracker preset (default: %(default)s)")
    k.add_argument(
        "--results-dir",
        type=Path,
        default=Path("out/kitti"),
        help="where tracking writes data_0/NNNN.txt (default: %(default)s)",
    )
    k.add_argument(
        "--results",
        type=Path,
        help="score the result files in this folder (NNNN.txt) instead of tracking",
    )
    k.add_argument("--json", type=Path, help="write the figures to this JSON file")
    k.add_argument(
        "--transport",
        choices=["local", "zenoh"],
        default="local",
        help="run the tracker in-process (local) or through the service (zenoh)",
    )
    k.add_argument(
        "--cv",
        choices=["loso"],
        help="cross-validate instead: leave one sequence out, choose settings on the others "
        "among a few structural candidates, pool the held-out results, compare with wod",
    )
    k.add_argument(
        "--candidates",
        help="with --cv: comma-separated candidate names from simpletrack.eval.cv's "
        "CANDIDATES and MOTION_CANDIDATES (default: all of CANDIDATES; wod is always first)",
    )
    k.add_argument(
        "--rule",
        choices=["higher", "gain"],
        default="higher",
        help="with --cv: when a candidate beats wod: higher (unchained sAMOTA and MOTA higher, "
        "no more ID switches) or gain (unchained sAMOTA +0.5 or more, MOTA not lower, no "
        "more ID switches) (default: %(default)s)",
    )
    k.add_argument(
        "--jobs", type=int, default=2, help="worker processes for --cv (default: %(default)s)"
    )
    k.set_defaults(func=run)


def _split(text: str, what: str) -> list[str]:
    items = [s.strip() for s in text.split(",") if s.strip()]
    if not items:
        raise UserError(f"--{what} is empty")
    return items


def _classes(text: str) -> list[str]:
    canonical = {c.lower(): c for c in KITTI_CLASSES}
    out = []
    for name in _split(text, "classes"):
        if name.lower() not in canonical:
            raise UserError(f"unknown class {name!r}; choose from {', '.join(KITTI_CLASSES)}")
        out.append(canonical[name.lower()])
    return out


def _config(name: str, classes: Sequence[str]) -> TrackerConfig:
    try:
        config = preset(name)
    except ValueError as exc:
        raise UserError(str(exc)) from None
    for cls in classes:
        try:
            config_class_code(config, cls)
        except KeyError as exc:
            raise UserError(f"preset {name!r}: {exc.args[0]}") from None
    return config


Tracking = Callable[[str, Sequence[SequenceFrame], TrackerConfig], list[Tracks]]


def _local(seq: str, frames: Sequence[SequenceFrame], config: TrackerConfig) -> list[Tracks]:
    return track_sequence(frames, config)


def track_all(
    data: Path,
    seqs: Sequence[str],
    classes: Sequence[str],
    config: TrackerConfig,
    out: Path,
    tracking: Tracking = _local,
) -> Path:
    """Track every sequence and write ``out/data_0/NNNN.txt``; returns that folder."""
    names = result_class_names(config, classes)
    for seq in seqs:
        try:
            frames = load_sequence(data, seq, config, classes)
        except (FileNotFoundError, ValueError) as exc:
            raise UserError(str(exc)) from None
        calib = read_calib(data / "calib" / f"{seq}.txt")
        write_tracked(out, seq, frames, tracking(seq, frames, config), names, calib)
    return out / "data_0"


def _table(metrics: dict[str, dict[str, float]]) -> None:
    from rich.console import Console
    from rich.table import Table

    # One row per figure, one column per class: fits a narrow terminal.
    table = Table(
        title="KITTI 3D MOT (3D IoU 0.25)",
        caption="HOTA: mean over 3D IoU alpha 0.05..0.95; IDF1: 3D IoU >= 0.25",
    )
    table.add_column("figure")
    for cls in metrics:
        table.add_column(cls, justify="right")
    for name in METRIC_NAMES:
        unit = "" if name in COUNTS else " %"
        table.add_row(
            name + unit,
            *(
                str(int(figs[name])) if name in COUNTS else f"{figs[name]:.2f}"
                for figs in metrics.values()
            ),
        )
    Console().print(table)


def _json_ready(metrics: dict[str, dict[str, float]]) -> dict[str, dict[str, float | None]]:
    return {
        cls: {
            n: (int(v) if n in COUNTS else round(v, 4)) if math.isfinite(v) else None
            for n, v in figs.items()
        }
        for cls, figs in metrics.items()
    }


def _track_over_zenoh(
    args: argparse.Namespace, seqs: Sequence[str], classes: Sequence[str], config: TrackerConfig
) -> Path:
    """The same tracking through a real ``simpletrack serve`` (spawned on a loopback port with
    lossless backpressure), one sensor stream per sequence."""
    from simpletrack.spawn import RemoteError, spawn_service, track_sequence_over_zenoh

    def remote(endpoint: str) -> Tracking:
        def run_one(seq: str, frames: Sequence[SequenceFrame], cfg: TrackerConfig) -> list[Tracks]:
            plain = [Frame(boxes=f.boxes, stamp=f.stamp) for f in frames]
            return track_sequence_over_zenoh(plain, cfg, connect=endpoint, sensor=f"kitti{seq}")

        return run_one

    try:
        with spawn_service(args.preset) as endpoint:
            print(f"tracking through a service at {endpoint}")
            return track_all(args.data, seqs, classes, config, args.results_dir, remote(endpoint))
    except RemoteError as exc:
        raise UserError(f"zenoh transport: {exc}") from None


def run(args: argparse.Namespace) -> int:
    try:
        args.data = data_dir(args.data, KITTI_DATA)
    except MissingData as exc:
        raise UserError(str(exc)) from None
    seqs = _split(args.seqs, "seqs")
    classes = _classes(args.classes)
    labels = args.data / "labels"
    missing = [s for s in seqs if not (labels / f"{s}.txt").is_file()]
    if missing:
        raise UserError(f"no labels for sequence(s) {', '.join(missing)} in {labels}")

    started = time.perf_counter()
    if args.cv is not None:
        return _cross_validate(args, seqs, classes)
    if args.results is not None:
        results = args.results
        if not results.is_dir():
            raise UserError(f"--results {results} is not a folder")
        if not (results / f"{seqs[0]}.txt").is_file() and (results / "data_0").is_dir():
            results = results / "data_0"  # the folder tracking writes, as --results-dir
    else:
        config = _config(args.preset, classes)
        for seq in seqs:
            calib = args.data / "calib" / f"{seq}.txt"
            if not calib.is_file():
                raise UserError(f"no calibration for sequence {seq}: {calib}")
        if args.transport == "zenoh":
            results = _track_over_zenoh(args, seqs, classes, config)
        else:
            results = track_all(args.data, seqs, classes, config, args.results_dir)
        print(
            f"tracked {len(seqs)} sequence(s) in {time.perf_counter() - started:.1f} s: {results}"
        )

    try:
        metrics = evaluate(results, labels, seqs, classes)
    except (FileNotFoundError, ValueError) as exc:
        raise UserError(str(exc)) from None
    _table(metrics)
    if args.json is not None:
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text(json.dumps(_json_ready(metrics), indent=1) + "\n")
        print(f"wrote {args.json}")
    return 0


def _cross_validate(args: argparse.Namespace, seqs: Sequence[str], classes: Sequence[str]) -> int:
    from simpletrack.eval.cv import (
        ALL_CANDIDATES,
        BASE,
        CANDIDATES,
        RULES,
        cross_validate,
        summary_rows,
    )

    if args.results is not None:
        raise UserError("--cv tracks the sequences itself: drop --results")
    if args.jobs < 1:
        raise UserError(f"--jobs must be at least 1, not {args.jobs}")
    candidates = list(CANDIDATES)
    if args.candidates is not None:
        known = {c.name: c for c in ALL_CANDIDATES}
        names = _split(args.candidates, "candidates")
        unknown = [n for n in names if n not in known]
        if unknown:
            raise UserError(f"unknown candidate(s) {', '.join(unknown)}; known: {', '.join(known)}")
        candidates = [known[BASE], *(known[n] for n in names if n != BASE)]
    started = time.perf_counter()
    try:
        cv = cross_validate(
            args.data, seqs, classes, candidates, jobs=args.jobs, rule=RULES[args.rule]
        )
    except (FileNotFoundError, ValueError) as exc:
        raise UserError(str(exc)) from None
    print(
        f"leave-one-sequence-out on {len(seqs)} sequences, {cv.configurations_tried} "
        f"configurations tried, rule {cv.rule}; official figures, unchained in brackets"
    )
    head = ("class", "settings", "sAMOTA %", "MOTA %", "IDS", *CV_EXTRA)
    lines: list[tuple[str, ...]] = [head]
    for cls, name, figs in summary_rows(cv):
        lines.append(
            (
                cls,
                name,
                f"{figs['sAMOTA']:.2f} ({figs['sAMOTA_u']:.2f})",
                f"{figs['MOTA']:.2f} ({figs['MOTA_u']:.2f})",
                str(int(figs["IDS"])),
                *(f"{figs[k]:.2f}" for k in CV_EXTRA),
            )
        )
    widths = [max(len(row[i]) for row in lines) for i in range(len(head))]
    for row in lines:
        print(
            "  ".join(
                v.ljust(w) if i < 2 else v.rjust(w)
                for i, (v, w) in enumerate(zip(row, widths, strict=True))
            )
        )
    for cls, r in cv.classes.items():
        verdict = "beats" if r.accepted else "does not beat"
        counts = Counter(r.choices.values()).most_common()
        print(
            f"{cls}: per fold {', '.join(f'{n} x{k}' for n, k in counts)}; the pooled held-out "
            f"result {verdict} wod; chosen on all {len(seqs)} sequences: {r.chosen_on_all}"
        )
    print(f"done in {time.perf_counter() - started:.0f} s")
    if args.json is not None:
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text(json.dumps(cv.to_json(), indent=1) + "\n")
        print(f"wrote {args.json}")
    return 0
