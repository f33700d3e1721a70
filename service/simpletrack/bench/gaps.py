"""How many track ids survive an outage: the KITTI train sequences replayed through the core
tracker with the frames of ``[cut, cut + gap)`` left out, as the service bridges a gap in a
sensor's stream (no reset; the next step predicts over the real dt, one missed frame for the
life cycle; the first frame after the gap is flagged ``after_gap`` as the service flags it).

    python -m simpletrack.bench.gaps --data ../shared/data/kitti --gaps 1,5,10,30 --json out/gaps.json

The KITTI folder is ``--data``, else ``$SIMPLETRACK_DATA/kitti``; there is no default folder.

Cuts every ``--every`` seconds (10 s: frames 100, 200, ...) where the sequence still has a
frame after the gap. An object is a ground-truth trajectory matched by the KITTI evaluator's
rule (3D IoU >= 0.25, per frame the most matches, then the least total 1 - IoU; the class's
neighbour, e.g. Van for Car, takes part in the matching but is not counted) to track X in the
last frame before the cut. It is *kept* if, in the first frame from ``cut + gap`` on in which it
is matched at all, it is matched to X; *changed* if matched to another id; *gone* if never
matched again (``gone_labelled`` of those are still in the labels after the gap). *swapped*
counts the ids X that, first matched after the gap, are matched to another object than the
one they held before: an object that took another's id (worse than a new id). ``gap 0`` is
the baseline: the cut frame simply follows, so ids changing without any outage show there.
Each gap has its own cuts (a long gap needs a long sequence), so ``alive`` differs by gap.

Why ids change: for the objects labelled in the first frame after the gap, the horizontal
distance from their old track's prediction (``pred_err``) and from its last position
(``still_err``) to the ground truth, medians in metres.
"""

from __future__ import annotations

import argparse
import json
import sys
from collections.abc import Sequence
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np
import numpy.typing as npt

from simpletrack.core.config import TrackerConfig, preset
from simpletrack.core.frames import Frame, Tracks
from simpletrack.core.solvers import linear_sum_assignment
from simpletrack.core.tracker import Tracker
from simpletrack.datasets.kitti import (
    FRAME_PERIOD,
    KITTI_CLASSES,
    TRAIN_SEQUENCES,
    SequenceFrame,
    camera_to_tracker,
    config_class_code,
    load_sequence,
    tracker_to_camera,
)
from simpletrack.datasets.paths import KITTI as KITTI_DATA
from simpletrack.datasets.paths import MissingData, data_dir, default_help
from simpletrack.eval.kitti_data import (
    DONTCARE,
    MAX_COST,
    TrackingRows,
    class_filter,
    read_tracking_file,
)
from simpletrack.eval.kitti_overlap import footprints_may_touch, iou3d_pairs

F64 = npt.NDArray[np.float64]
I64 = npt.NDArray[np.int64]

DEFAULT_GAPS_S = (1.0, 5.0, 10.0, 30.0)
DEFAULT_EVERY_S = 10.0
_INFEASIBLE = 1e9
_EMPTY = np.zeros(0, np.int64)


# ----------------------------------------------------------------------------- matching
def evaluator_matches(gt_cam: F64, trk_cam: F64) -> tuple[I64, I64]:
    """(ground-truth index, track index) pairs the KITTI evaluator matches in one frame."""
    n, m = len(gt_cam), len(trk_cam)
    if n == 0 or m == 0:
        return _EMPTY, _EMPTY
    gi, ti = np.repeat(np.arange(n), m), np.tile(np.arange(m), n)
    cost = np.full(n * m, _INFEASIBLE)
    near = np.flatnonzero(footprints_may_touch(gt_cam[gi], trk_cam[ti]))
    cost[near] = 1.0 - iou3d_pairs(gt_cam[gi[near]], trk_cam[ti[near]])
    cost[cost > MAX_COST] = _INFEASIBLE
    matrix = cost.reshape(n, m)
    # As the evaluator: only rows and columns with a candidate pair enter the assignment.
    feasible = matrix < _INFEASIBLE
    rows, cols = np.flatnonzero(feasible.any(axis=1)), np.flatnonzero(feasible.any(axis=0))
    if rows.size == 0:
        return _EMPTY, _EMPTY
    sub = matrix[np.ix_(rows, cols)]
    r, c = linear_sum_assignment(sub)
    ok = sub[r, c] < _INFEASIBLE
    return rows[r[ok]].astype(np.int64), cols[c[ok]].astype(np.int64)


@dataclass(frozen=True, slots=True)
class ClassTruth:
    """One class's labels of one sequence (with its neighbour, without DontCare), by frame."""

    code: int
    rows: TrackingRows
    is_object: npt.NDArray[np.bool_]  # the class itself, not its neighbour
    bounds: I64  # rows of frame k: bounds[k] .. bounds[k + 1]
    last_frame: dict[int, int]  # object id -> last labelled frame

    @classmethod
    def load(cls, labels: TrackingRows, name: str, code: int, n_frames: int) -> ClassTruth:
        rows = labels.take(class_filter(labels, name.lower()) & (labels.kind != DONTCARE))
        rows = rows.take(np.argsort(rows.frame, kind="stable"))
        is_object = rows.kind == name.lower()
        # Rows are in frame order, so an object's last row (first from the end) is its last frame.
        ids, at = np.unique(rows.track_id[is_object][::-1], return_index=True)
        last = dict(zip(ids.tolist(), rows.frame[is_object][::-1][at].tolist(), strict=True))
        bounds = np.searchsorted(rows.frame, np.arange(n_frames + 1)).astype(np.int64)
        return cls(code, rows, np.asarray(is_object), bounds, last)

    def frame_rows(self, k: int) -> slice:
        return slice(int(self.bounds[k]), int(self.bounds[k + 1]))

    def matched(self, k: int, tracks: Tracks) -> tuple[I64, I64]:
        """(object id, track id) of the class's objects matched in frame ``k``."""
        sl = self.frame_rows(k)
        mine = np.flatnonzero(tracks.boxes.cls == self.code)
        gi, ti = evaluator_matches(self.rows.cam[sl], tracker_to_camera(tracks.boxes.params[mine]))
        obj = self.is_object[sl][gi]
        return self.rows.track_id[sl][gi[obj]], tracks.ids[mine[ti[obj]]]


# ----------------------------------------------------------------------------- counting
@dataclass(slots=True)
class Survival:
    """Counts of one gap (one class, or summed)."""

    cuts: int = 0
    alive: int = 0
    kept: int = 0
    changed: int = 0
    gone: int = 0
    gone_labelled: int = 0
    swapped: int = 0
    pred_err: list[float] = field(default_factory=list)
    still_err: list[float] = field(default_factory=list)

    def add(self, other: Survival) -> None:
        self.cuts += other.cuts
        self.alive += other.alive
        self.kept += other.kept
        self.changed += other.changed
        self.gone += other.gone
        self.gone_labelled += other.gone_labelled
        self.swapped += other.swapped
        self.pred_err += other.pred_err
        self.still_err += other.still_err

    @property
    def share_kept(self) -> float | None:
        seen = self.kept + self.changed
        return self.kept / seen if seen else None

    def summary(self) -> dict[str, float | int | None]:
        out: dict[str, float | int | None] = {
            k: v for k, v in asdict(self).items() if k not in ("pred_err", "still_err")
        }
        share = self.share_kept
        out["share_kept"] = None if share is None else round(share, 4)
        for name in ("pred_err", "still_err"):
            errs = getattr(self, name)
            out[f"{name}_median_m"] = round(float(np.median(errs)), 2) if errs else None
        return out


@dataclass(slots=True)
class _Alive:
    """The objects of one class alive at one cut, and what became of them."""

    obj: I64
    before: I64
    after: I64  # -1 until matched after the gap
    holder: I64  # the object ``before`` is first matched to after the gap, -1 until then

    def resolve(self, obj: I64, ids: I64) -> None:
        """Record the track ids of the still open objects among those matched now, and the
        objects the old ids are matched to."""
        free = np.flatnonzero(self.holder == -1)
        if free.size and ids.size:
            by_id = np.argsort(ids)
            pos = np.minimum(np.searchsorted(ids[by_id], self.before[free]), ids.size - 1)
            hit = ids[by_id][pos] == self.before[free]
            self.holder[free[hit]] = obj[by_id][pos[hit]]
        open_ = np.flatnonzero(self.after == -1)
        if open_.size == 0 or obj.size == 0:
            return
        order = np.argsort(obj)
        pos = np.minimum(np.searchsorted(obj[order], self.obj[open_]), obj.size - 1)
        hit = obj[order][pos] == self.obj[open_]
        self.after[open_[hit]] = ids[order][pos[hit]]

    def horizon(self, truth: ClassTruth) -> int:
        """The last labelled frame of any open object (-1: none is open)."""
        return max((truth.last_frame[o] for o in self.obj[self.after == -1].tolist()), default=-1)


def _errors(
    tracker: Tracker, alive: _Alive, truth: ClassTruth, k: int, stamp: float
) -> tuple[list[float], list[float]]:
    """Horizontal distance of each alive object's ground truth in frame ``k`` to its old
    track's prediction and to the track's last position (objects labelled in ``k`` only)."""
    sl = truth.frame_rows(k)
    here = np.flatnonzero(truth.is_object[sl])
    obj_here = truth.rows.track_id[sl][here]
    tr = tracker.tracks
    if here.size == 0 or len(tr) == 0 or alive.obj.size == 0:
        return [], []
    by_obj = np.argsort(obj_here)
    g = np.minimum(np.searchsorted(obj_here[by_obj], alive.obj), here.size - 1)
    by_id = np.argsort(tr.ids)
    t = np.minimum(np.searchsorted(tr.ids[by_id], alive.before), len(tr) - 1)
    ok = (obj_here[by_obj][g] == alive.obj) & (tr.ids[by_id][t] == alive.before)
    gt_xy = camera_to_tracker(truth.rows.cam[sl][here[by_obj][g[ok]]])[:, :2]
    j = by_id[t[ok]]
    last = tr.x[j, :2]
    guess = last + tr.x[j, 7:9] * (stamp - tr.t_update[j])[:, None]
    pred = np.hypot(*(guess - gt_xy).T)
    still = np.hypot(*(last - gt_xy).T)
    return pred.tolist(), still.tolist()


def cut_frames(n_frames: int, every_s: float) -> list[int]:
    step = max(1, round(every_s / FRAME_PERIOD))
    return list(range(step, n_frames, step))


def sequence_survival(
    frames: Sequence[SequenceFrame],
    truths: dict[str, ClassTruth],
    config: TrackerConfig,
    gaps_s: Sequence[float],
    every_s: float = DEFAULT_EVERY_S,
) -> dict[float, dict[str, Survival]]:
    """gap (s) -> class -> counts, over the cuts of one sequence."""
    n = len(frames)
    cuts = cut_frames(n, every_s)
    tracker = Tracker(config)
    snapshots: dict[int, bytes] = {}
    alive_at: dict[int, dict[str, tuple[I64, I64]]] = {}
    # One uninterrupted pass: the tracker's state at each cut, and who is matched just before.
    for k in range(max(cuts, default=0)):
        out = tracker.step(Frame(boxes=frames[k].boxes, stamp=frames[k].stamp))
        if k + 1 in cuts:
            snapshots[k + 1] = tracker.to_bytes()
            alive_at[k + 1] = {name: t.matched(k, out) for name, t in truths.items()}

    result = {g: {name: Survival() for name in truths} for g in gaps_s}
    for g in gaps_s:
        skip = round(g / FRAME_PERIOD)
        for cut in cuts:
            if cut + skip >= n:
                continue
            fork = Tracker.from_bytes(snapshots[cut])
            alive = {
                name: _Alive(obj, before, np.full(len(obj), -1, np.int64), np.full(len(obj), -1))
                for name, (obj, before) in alive_at[cut].items()
            }
            first = cut + skip
            for name, truth in truths.items():
                pred, still = _errors(fork, alive[name], truth, first, frames[first].stamp)
                result[g][name].pred_err += pred
                result[g][name].still_err += still
            for k in range(first, n):
                # Nothing left to learn once every open object has left the labels.
                if max(a.horizon(truths[name]) for name, a in alive.items()) < k:
                    break
                bridged = skip > 0 and k == first
                out = fork.step(
                    Frame(boxes=frames[k].boxes, stamp=frames[k].stamp, after_gap=bridged)
                )
                for name, truth in truths.items():
                    alive[name].resolve(*truth.matched(k, out))
            for name, a in alive.items():
                s = result[g][name]
                gone = a.after == -1
                s.cuts += 1
                s.alive += len(a.obj)
                s.kept += int((~gone & (a.after == a.before)).sum())
                s.changed += int((~gone & (a.after != a.before)).sum())
                s.gone += int(gone.sum())
                s.swapped += int(((a.holder != -1) & (a.holder != a.obj)).sum())
                s.gone_labelled += sum(
                    truths[name].last_frame.get(int(o), -1) >= first for o in a.obj[gone].tolist()
                )
    return result


def measure(
    data: Path,
    seqs: Sequence[str],
    classes: Sequence[str],
    config: TrackerConfig,
    gaps_s: Sequence[float],
    every_s: float = DEFAULT_EVERY_S,
) -> dict[float, dict[str, Survival]]:
    """gap (s) -> class -> counts summed over the sequences."""
    total = {g: {name: Survival() for name in classes} for g in gaps_s}
    for seq in seqs:
        frames = load_sequence(data, seq, config, classes)
        labels = read_tracking_file(data / "labels" / f"{seq}.txt", with_score=False)
        truths = {
            name: ClassTruth.load(labels, name, config_class_code(config, name), len(frames))
            for name in classes
        }
        for g, per_class in sequence_survival(frames, truths, config, gaps_s, every_s).items():
            for name, s in per_class.items():
                total[g][name].add(s)
    return total


# ----------------------------------------------------------------------------- report
def report(result: dict[float, dict[str, Survival]]) -> dict[str, object]:
    gaps = []
    for g, per_class in result.items():
        all_classes = Survival()
        for s in per_class.values():
            all_classes.add(s)
        all_classes.cuts = max((s.cuts for s in per_class.values()), default=0)
        gaps.append(
            {
                "gap_s": g,
                **all_classes.summary(),
                "classes": {name: s.summary() for name, s in per_class.items()},
            }
        )
    return {"gaps": gaps}


def _fmt(v: object) -> str:
    if v is None:
        return "-"
    if isinstance(v, float):
        return f"{v:g}"
    return str(v)


def table(doc: dict[str, object]) -> str:
    cols = ("cuts", "alive", "kept", "changed", "swapped", "gone", "gone_labelled", "share_kept",
            "pred_err_median_m", "still_err_median_m")  # fmt: skip
    head = ("gap s", *cols)
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    gaps = doc["gaps"]
    assert isinstance(gaps, list)
    for row in gaps:
        lines.append("| " + " | ".join([_fmt(row["gap_s"]), *(_fmt(row[c]) for c in cols)]) + " |")
    return "\n".join(lines)


def _gaps(text: str) -> list[float]:
    """The gaps asked for, in seconds, and the no-gap baseline."""
    try:
        gaps = sorted({float(s) for s in text.split(",") if s.strip()} | {0.0})
    except ValueError:
        raise SystemExit(f"--gaps: not a comma-separated list of seconds: {text!r}") from None
    if gaps[0] < 0:
        raise SystemExit(f"--gaps: a gap cannot be negative: {text!r}")
    return gaps


def main(argv: Sequence[str] | None = None) -> int:
    p = argparse.ArgumentParser(
        prog="python -m simpletrack.bench.gaps",
        description="How many KITTI track ids survive a gap of G seconds in the stream "
        "(the no-gap baseline, gap 0, is always included).",
    )
    p.add_argument(
        "--data",
        type=Path,
        metavar="FOLDER",
        help=f"KITTI folder: labels/, calib/, detections/pointrcnn/ ({default_help(KITTI_DATA)})",
    )
    p.add_argument(
        "--gaps",
        default=",".join(f"{g:g}" for g in DEFAULT_GAPS_S),
        help="seconds, comma-separated",
    )
    p.add_argument("--every", type=float, default=DEFAULT_EVERY_S, help="seconds between cuts")
    p.add_argument("--seqs", default=",".join(TRAIN_SEQUENCES))
    p.add_argument("--classes", default=",".join(KITTI_CLASSES))
    p.add_argument("--preset", default="kitti")
    p.add_argument("--json", type=Path, help="write the counts to this JSON file")
    args = p.parse_args(argv)
    try:
        args.data = data_dir(args.data, KITTI_DATA)
    except MissingData as exc:
        p.exit(2, f"{p.prog}: error: {exc}\n")
    gaps = _gaps(args.gaps)
    seqs = [s.strip() for s in args.seqs.split(",") if s.strip()]
    classes = [c.strip() for c in args.classes.split(",") if c.strip()]
    try:
        result = measure(args.data, seqs, classes, preset(args.preset), gaps, args.every)
    except (FileNotFoundError, KeyError, ValueError) as exc:
        raise SystemExit(f"gaps: {exc}") from None
    doc: dict[str, object] = {
        "preset": args.preset,
        "seqs": seqs,
        "every_s": args.every,
        "match": "KITTI evaluator: 3D IoU >= 0.25, Hungarian per frame",
        **report(result),
    }
    print(table(doc))
    if args.json is not None:
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text(json.dumps(doc, indent=1) + "\n")
        print(f"wrote {args.json}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
