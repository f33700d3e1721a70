"""Leave-one-sequence-out cross-validation of tracker settings on KITTI (``simpletrack eval
kitti --cv loso``): the only way the ``kitti`` preset is chosen.

The steps:
1. Candidates: a short list of structural settings (``CANDIDATES``), each a few per-class
   fields over the paper's WOD settings (``wod`` itself first). Each is tried per class.
2. Tracking: every sequence once per candidate and class (classes are tracked apart: the
   association is class-gated and NMS class-aware), result files kept per candidate.
3. Folds: for each held-out sequence and class, every candidate is scored on the other
   sequences. Scores for choosing are the unchained sAMOTA and MOTA (``tune.unchained_figures``:
   the official evaluator's re-averaging can drop a whole track one ulp under a threshold, a
   rounding lottery that must not decide). The choice: among candidates with no more ID
   switches than ``wod`` and a higher unchained sAMOTA and MOTA than it on those sequences,
   the one with the highest sum; else ``wod``.
4. Pooling: each held-out sequence's result file, from the candidate chosen without it, goes
   into one folder; the pooled folder is scored once (official and unchained figures), next
   to every candidate with fixed settings on the same sequences.
5. Verdict: the same choice made on all the sequences is the preset the procedure gives; it is
   accepted for a class only if the pooled held-out figures beat ``wod``'s (unchained sAMOTA
   and MOTA higher, no more ID switches).
"""

from __future__ import annotations

import multiprocessing as mp
import shutil
import tempfile
from collections.abc import Callable, Mapping, Sequence
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

from simpletrack.core.config import TrackerConfig, preset
from simpletrack.datasets.kitti import (
    SequenceFrame,
    load_sequence,
    read_calib,
    result_class_names,
    write_tracked,
)
from simpletrack.eval.kitti import evaluate_problem
from simpletrack.eval.kitti_data import build_problem
from simpletrack.eval.tracking import track_sequence
from simpletrack.eval.tune import build_config, unchained_figures

BASE = "wod"


@dataclass(frozen=True, slots=True)
class Candidate:
    """Per-class fields (``ClassConfig``) changed from the ``wod`` settings."""

    name: str
    changes: tuple[tuple[str, Any], ...] = ()

    def config(self, cls: str) -> TrackerConfig:
        return build_config(preset(BASE), cls, dict(self.changes), {})

    def in_every_class(self, base: TrackerConfig) -> TrackerConfig:
        """``base`` with these changes in each of its classes (the simulator's check, the
        benchmark's cost of an option)."""
        changes = dict(self.changes)
        classes = {n: {**c.model_dump(), **changes} for n, c in base.classes.items()}
        return base.with_overrides(classes=classes)


# Fixed before any cross-validation ran, from the mechanisms' papers, not from figures: each
# mechanism alone at its published or structural setting, and the combinations its paper uses.
CANDIDATES: tuple[Candidate, ...] = (
    Candidate(BASE),
    # CBMOT: the track's score fused with each matched detection's, decaying in between.
    Candidate("fused", (("track_score", "fused"),)),
    # CBMOT's life cycle: a longer life ended by the fused score instead of a frame count.
    Candidate(
        "fused_life",
        (("track_score", "fused"), ("max_age", 4), ("delete_below", 0.3)),
    ),
    # AB3DMOT's output: a confirmed track is written through its (max_age - 1) coasting frames.
    Candidate("coast", (("coast_output", 1),)),
    # Fast-Poly: fused scores and one coasting box per gap.
    Candidate("fused_coast", (("track_score", "fused"), ("coast_output", 1))),
    # One more frame of life: identity through a two-frame occlusion.
    Candidate("age3", (("max_age", 3),)),
    # PC3T / CasTrack: a longer life with a gate that widens while a track coasts.
    Candidate("widen", (("max_age", 3), ("gate_widening", 0.25))),
    # RobMOT: deletion when the predicted position is too uncertain, not after a frame count.
    Candidate("std", (("max_age", 6), ("max_position_std", 2.0))),
    # AB3DMOT's small-object association: centre distance under 2 m.
    Candidate("l2", (("metric", "l2"), ("max_distance", 2.0), ("stage2_max_distance", 2.0))),
    # The paper's pedestrian threshold for every class: tracks start from weaker detections.
    Candidate("start_0.5", (("score_high", 0.5),)),
    # The structural ones together.
    Candidate(
        "fused_age3_widen",
        (("track_score", "fused"), ("max_age", 3), ("gate_widening", 0.25)),
    ),
)

# The motion models and the lost-track life cycle (docs/MOTION.md), fixed before their own
# runs (docs/KITTI_TUNING.md, "Motion models and lost tracks"); by name with --candidates.
MOTION_CANDIDATES: tuple[Candidate, ...] = (
    # Motion models per class (docs/MOTION.md; their noise the models' defaults, written
    # down before any run): Fast-Poly's constant acceleration, constant turn rate and
    # acceleration (its vehicles), and bicycle model (its two-wheelers).
    Candidate("ca", (("motion_model", "ca"),)),
    Candidate("ctra", (("motion_model", "ctra"),)),
    Candidate("bicycle", (("motion_model", "bicycle"),)),
    # ImmortalTracker: a lost track is kept (10 s here, its paper: for ever) and re-associated
    # under the ordinary gate, or under the likelihood gate at one new object per 400 m^2.
    Candidate("immortal", (("revive_frames", 100),)),
    Candidate("immortal_gated", (("revive_frames", 100), ("revive_gate", 12.0))),
    # Both families together: a turn model carries the lost track's prediction.
    Candidate(
        "ctra_immortal_gated",
        (("motion_model", "ctra"), ("revive_frames", 100), ("revive_gate", 12.0)),
    ),
    # The turn models under the process noise the simulator chose for them (not KITTI:
    # `python -m simpletrack.sim.motion_check --seed 1 --noise-grid`), 0.1 on the box states
    # instead of AB3DMOT's 1.
    Candidate("ctra_sim_noise", (("motion_model", "ctra"), ("process_noise", (0.1, 1.0)))),
    Candidate("bicycle_sim_noise", (("motion_model", "bicycle"), ("process_noise", (0.1, 1.0)))),
    Candidate(
        "ctra_sim_noise_immortal_gated",
        (
            ("motion_model", "ctra"),
            ("process_noise", (0.1, 1.0)),
            ("revive_frames", 100),
            ("revive_gate", 12.0),
        ),
    ),
)

# Every candidate a run may name.
ALL_CANDIDATES = CANDIDATES + MOTION_CANDIDATES


@dataclass
class ClassResult:
    """One class's cross-validation: figures are ``evaluate_problem``'s plus ``sAMOTA_u`` and
    ``MOTA_u`` (unchained)."""

    cls: str
    fixed: dict[str, dict[str, float]]  # candidate -> its figures on every sequence
    loso: dict[str, float]  # the pooled held-out figures of the choice
    choices: dict[str, str]  # held-out sequence -> the candidate chosen on the others
    chosen_on_all: str  # the choice made on every sequence: the preset's settings
    accepted: bool  # the pooled held-out figures beat wod's


@dataclass
class CrossValidation:
    seqs: list[str]
    candidates: list[dict[str, Any]]
    rule: str = "higher"
    classes: dict[str, ClassResult] = field(default_factory=dict)

    @property
    def configurations_tried(self) -> int:
        return len(self.candidates) * len(self.classes)

    def to_json(self) -> dict[str, Any]:
        return {
            "seqs": self.seqs,
            "candidates": self.candidates,
            "rule": self.rule,
            "configurations_tried": self.configurations_tried,
            "classes": {c: asdict(r) for c, r in self.classes.items()},
        }


@dataclass(frozen=True, slots=True)
class Rule:
    """When a candidate's figures beat ``wod``'s: unchained sAMOTA higher by more than
    ``min_gain`` points (at least that much, when it is positive), unchained MOTA higher
    (``mota_higher``) or not lower, and no more ID switches."""

    name: str
    min_gain: float = 0.0
    mota_higher: bool = True

    def beats(self, figs: dict[str, float], base: dict[str, float]) -> bool:
        gain = figs["sAMOTA_u"] - base["sAMOTA_u"]
        samota_ok = gain >= self.min_gain if self.min_gain > 0 else gain > 0
        mota = figs["MOTA_u"] - base["MOTA_u"]
        mota_ok = mota > 0 if self.mota_higher else mota >= 0
        return samota_ok and mota_ok and figs["IDS"] <= base["IDS"]


RULES = {
    # The procedure's rule since it was written: higher on both figures.
    "higher": Rule("higher"),
    # The motion-model and life-cycle candidates' rule, fixed by their issue before any run:
    # +0.5 unchained sAMOTA or more, MOTA not worse.
    "gain": Rule("gain", min_gain=0.5, mota_higher=False),
}


def choose(
    scores: dict[str, dict[str, float]], order: Sequence[str], rule: Rule = RULES["higher"]
) -> str:
    """Step 3's rule: the best candidate that beats ``wod`` on these scores, else ``wod``."""
    base = scores[BASE]
    better = [c for c in order if c != BASE and rule.beats(scores[c], base)]
    if not better:
        return BASE
    return max(better, key=lambda c: (scores[c]["sAMOTA_u"] + scores[c]["MOTA_u"], -order.index(c)))


def fold_choices(
    scores: Mapping[tuple[str, tuple[str, ...]], dict[str, float]],
    seqs: Sequence[str],
    names: Sequence[str],
    rule: Rule = RULES["higher"],
) -> dict[str, str]:
    """Held-out sequence -> the candidate ``choose`` picks from ``scores[candidate, training
    sequences]``, the training sequences being all but the held-out one."""
    choices = {}
    for held in seqs:
        train = tuple(s for s in seqs if s != held)
        choices[held] = choose({c: scores[c, train] for c in names}, names, rule)
    return choices


# ----------------------------------------------------------------------------- workers
@dataclass
class _Worker:
    data: Path
    root: Path
    frames: dict[tuple[str, str], list[SequenceFrame]] = field(default_factory=dict)


_W: _Worker | None = None


def _init(data: Path, root: Path) -> None:
    global _W
    _W = _Worker(data, root)


def _results_dir(root: Path, cls: str, name: str) -> Path:
    return root / cls / name / "data_0"


def _track(job: tuple[str, Candidate, tuple[str, ...]]) -> None:
    """Step 2: one candidate, one class, every sequence."""
    assert _W is not None
    cls, cand, seqs = job
    config = cand.config(cls)
    names = result_class_names(config, [cls])
    out = _results_dir(_W.root, cls, cand.name).parent
    for seq in seqs:
        key = (cls, seq)
        if key not in _W.frames:
            _W.frames[key] = load_sequence(_W.data, seq, config, [cls])
        frames = _W.frames[key]
        calib = read_calib(_W.data / "calib" / f"{seq}.txt")
        write_tracked(out, seq, frames, track_sequence(frames, config), names, calib)


def _figures(job: tuple[str, str, tuple[str, ...]]) -> dict[str, float]:
    """Official and unchained figures of one results folder on some sequences."""
    assert _W is not None
    cls, name, seqs = job
    problem = build_problem(_W.data / "labels", _results_dir(_W.root, cls, name), seqs, cls)
    return {**evaluate_problem(problem), **unchained_figures(problem)}


# ----------------------------------------------------------------------------- the run
def cross_validate(
    data: Path,
    seqs: Sequence[str],
    classes: Sequence[str],
    candidates: Sequence[Candidate] = CANDIDATES,
    jobs: int = 2,
    progress: Callable[[str], None] = print,
    rule: Rule = RULES["higher"],
) -> CrossValidation:
    if len(seqs) < 2:
        raise ValueError(f"leave-one-out needs at least 2 sequences, not {len(seqs)}")
    names = [c.name for c in candidates]
    if names[0] != BASE or len(set(names)) != len(names):
        raise ValueError(f"candidates must start with {BASE!r} and have unique names: {names}")
    for cand in candidates:
        for cls in classes:
            cand.config(cls)  # a bad field fails here, before any tracking
    seqs = tuple(seqs)
    result = CrossValidation(
        list(seqs), [{"name": c.name, "changes": dict(c.changes)} for c in candidates], rule.name
    )
    with tempfile.TemporaryDirectory(prefix="simpletrack-cv-") as tmp:
        root = Path(tmp)
        ctx = mp.get_context("spawn")
        with ctx.Pool(max(1, jobs), initializer=_init, initargs=(data, root)) as pool:
            tracking = [(cls, c, seqs) for cls in classes for c in candidates]
            progress(f"tracking {len(seqs)} sequences x {len(tracking)} (class, candidate)")
            pool.map(_track, tracking)
            folds: list[str | None] = [None, *seqs]
            scoring = [
                (cls, c.name, tuple(s for s in seqs if s != held))
                for cls in classes
                for c in candidates
                for held in folds
            ]
            progress(f"scoring {len(scoring)} (class, candidate, fold) evaluations")
            scored = dict(zip(scoring, pool.map(_figures, scoring), strict=True))
            for cls in classes:
                choices = fold_choices(
                    {(c, train): f for (k, c, train), f in scored.items() if k == cls},
                    seqs,
                    names,
                    rule,
                )
                pooled = _results_dir(root, cls, "loso")
                pooled.mkdir(parents=True)
                for held, name in choices.items():
                    shutil.copy(_results_dir(root, cls, name) / f"{held}.txt", pooled)
                _init(data, root)
                loso = _figures((cls, "loso", seqs))
                fixed = {c: scored[cls, c, seqs] for c in names}
                result.classes[cls] = ClassResult(
                    cls=cls,
                    fixed=fixed,
                    loso=loso,
                    choices=choices,
                    chosen_on_all=choose(fixed, names, rule),
                    accepted=rule.beats(loso, fixed[BASE]),
                )
                progress(f"{cls}: held-out choices {choices}")
    return result


def summary_rows(cv: CrossValidation) -> list[tuple[str, str, dict[str, float]]]:
    """(class, row name, figures): wod, each candidate alone, then the cross-validated choice."""
    rows = []
    for cls, r in cv.classes.items():
        for name, figs in r.fixed.items():
            rows.append((cls, name, figs))
        rows.append((cls, "loso (chosen per fold)", r.loso))
    return rows
