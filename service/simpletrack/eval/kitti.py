"""KITTI 3D MOT evaluation exactly as AB3DMOT's evaluator computes it (``3D 0.25``).

Rules: ../shared/spec/KITTI_EVAL.md. Per class, summed over sequences: one run without a
score threshold gives the recall points; one run per recall point gives sAMOTA, AMOTA and
AMOTP; one more run at the best-MOTA threshold gives the other figures. Each run re-averages
the previous run's per-track means box by box (the reference's in-place overwrite), which must
be chained exactly to reproduce its sAMOTA. HOTA (DetA, AssA, LocA) and IDF1 (IDP, IDR), which
AB3DMOT's evaluator does not compute, are TrackEval's, on the final run's boxes
(``simpletrack.eval.hota``, ``simpletrack.eval.identity``).

Speed: the per-pair IoU3D is computed once (``kitti_eval_data``); a frame's Hungarian
assignment depends only on which of its candidate tracker boxes survive the threshold, so it
is memoised on that pattern.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import numpy.typing as npt

from simpletrack.core.solvers import linear_sum_assignment
from simpletrack.eval.hota import hota_figures, kitti_boxes
from simpletrack.eval.identity import identity_counts
from simpletrack.eval.kitti_data import Problem, build_problem

F64 = npt.NDArray[np.float64]
I64 = npt.NDArray[np.int64]
Bool = npt.NDArray[np.bool_]

RECALL_POINTS = 40
NO_THRESHOLD = -10000.0
_INFEASIBLE = 1e9
METRIC_NAMES = (
    "sAMOTA", "AMOTA", "AMOTP", "MOTA", "MOTP", "IDS", "FRAG", "FP", "FN", "TP",
    "Recall", "Precision", "MT", "ML", "HOTA", "DetA", "AssA", "LocA", "IDF1", "IDP", "IDR",
)  # fmt: skip


@dataclass(frozen=True, slots=True)
class RunCounts:
    """What one evaluation run at one score threshold counts."""

    tp: int
    fp: int
    fn: int
    ids: int
    frag: int
    n_gt: int
    mt: int
    ml: int
    n_traj: int  # trajectories not entirely ignored
    motp_sum: float
    tp_scores: F64
    kept: Bool  # tracker boxes of tracks at or above the threshold
    matched: I64  # the matched candidate pairs

    @property
    def mota(self) -> float:
        return 1.0 - (self.fn + self.fp + self.ids) / self.n_gt if self.n_gt else float("nan")

    @property
    def motp(self) -> float:
        return self.motp_sum / self.tp if self.tp else 0.0

    def smota(self, recall: float) -> float:
        if not self.n_gt or recall <= 0:
            return 0.0
        errors = self.fn + self.fp + self.ids - (1.0 - recall) * self.n_gt
        return min(1.0, max(0.0, 1.0 - errors / (recall * self.n_gt)))


class ClassEvaluation:
    """The evaluator's state for one class: the problem and the chained box scores."""

    def __init__(self, problem: Problem) -> None:
        self.p = problem
        self.box_score = problem.trk_score.copy()
        self._memo: list[dict[bytes, I64]] = [{} for _ in range(len(problem.segments) - 1)]
        # Boxes of every track in frame order, as columns: column j holds the j-th box of each
        # track that has one, so the per-track sums add box by box like the reference's sum().
        order = np.lexsort((problem.trk_frame, problem.trk_track))
        track = problem.trk_track[order]
        self._track_len = np.bincount(track, minlength=problem.n_tracks).astype(np.float64)
        first = np.searchsorted(track, track, side="left")
        pos = np.arange(len(track)) - first
        self._columns = [order[pos == j] for j in range(int(pos.max(initial=-1)) + 1)]
        # Ground truth in trajectory order (frames ascending) for switches and fragments.
        self._traj_order = np.lexsort((problem.gt_frame, problem.gt_traj))

    # ----------------------------------------------------------------- thresholding
    def _rescore(self) -> F64:
        """Each track's mean of its boxes' current scores; boxes take their track's mean."""
        acc = np.zeros(self.p.n_tracks)
        for col in self._columns:
            acc[self.p.trk_track[col]] += self.box_score[col]
        mean = acc / np.maximum(self._track_len, 1.0)
        self.box_score = mean[self.p.trk_track]
        return mean

    # ----------------------------------------------------------------- matching
    def _match(self, kept: Bool) -> I64:
        """Indices of the matched candidate pairs, frame by frame."""
        p = self.p
        usable = kept[p.pair_trk]
        chosen: list[I64] = []
        for s in range(len(p.segments) - 1):
            lo, hi = int(p.segments[s]), int(p.segments[s + 1])
            mask = usable[lo:hi]
            key = mask.tobytes()
            hit = self._memo[s].get(key)
            if hit is None:
                hit = self._solve(lo + np.flatnonzero(mask))
                self._memo[s][key] = hit
            chosen.append(hit)
        return np.concatenate(chosen) if chosen else np.zeros(0, np.int64)

    def _solve(self, idx: I64) -> I64:
        """Hungarian assignment over one frame's usable candidate pairs: the most matches,
        then the least total cost (pairs below the IoU threshold are not candidates)."""
        if len(idx) <= 1:
            return idx.astype(np.int64)
        rows, ri = np.unique(self.p.pair_gt[idx], return_inverse=True)
        cols, ci = np.unique(self.p.pair_trk[idx], return_inverse=True)
        if len(rows) == len(idx) and len(cols) == len(idx):
            return idx.astype(np.int64)  # disjoint pairs: every one matches
        cost = np.full((len(rows), len(cols)), _INFEASIBLE)
        cost[ri, ci] = self.p.pair_cost[idx]
        which = np.full((len(rows), len(cols)), -1, dtype=np.int64)
        which[ri, ci] = idx
        r, c = linear_sum_assignment(cost)
        ok = cost[r, c] < _INFEASIBLE
        return np.asarray(which[r[ok], c[ok]], dtype=np.int64)

    # ----------------------------------------------------------------- one run
    def run(self, threshold: float) -> RunCounts:
        p = self.p
        mean = self._rescore()
        kept = (mean >= threshold)[p.trk_track]
        sel = self._match(kept)
        gt_trk = np.full(len(p.gt_frame), -1, dtype=np.int64)
        gt_trk[p.pair_gt[sel]] = p.trk_track[p.pair_trk[sel]]
        trk_matched = np.zeros(len(p.trk_frame), dtype=bool)
        trk_matched[p.pair_trk[sel]] = True
        ign = p.gt_ignored
        ids, frag, mt, ml, n_traj = self._trajectories(gt_trk)
        return RunCounts(
            tp=len(sel),
            fp=int((kept & ~trk_matched & ~p.trk_ignorable).sum()),
            fn=int(((gt_trk == -1) & ~ign).sum()),
            ids=ids,
            frag=frag,
            n_gt=int((~ign).sum()),
            mt=mt,
            ml=ml,
            n_traj=n_traj,
            motp_sum=float((1.0 - p.pair_cost[sel]).sum()),
            tp_scores=self.box_score[p.pair_trk[sel]],
            kept=kept,
            matched=sel,
        )

    def _trajectories(self, gt_trk: I64) -> tuple[int, int, int, int, int]:
        """ID switches, fragments, mostly tracked, mostly lost, counted trajectories."""
        o = self._traj_order
        g = gt_trk[o]
        ign = self.p.gt_ignored[o]
        traj = self.p.gt_traj[o]
        n = len(g)
        if n == 0:
            return 0, 0, 0, 0, 0
        start = np.diff(traj, prepend=-1) != 0
        end = np.append(start[1:], True)
        # last_id after each frame: the first frame sets it to its id (ignored or not), an
        # ignored frame resets it to -1, a matched frame sets it, a missed one keeps it.
        sets = start | ign | (g != -1)
        value = np.where(start, g, np.where(ign, -1, g))
        last_after = value[np.maximum.accumulate(np.where(sets, np.arange(n), 0))]
        last = np.concatenate([[-1], last_after[:-1]])  # before this frame's checks
        prev = np.concatenate([[-1], g[:-1]])
        nxt = np.append(g[1:], -1)
        checked = ~start & ~ign
        tracked_here = g != -1
        switch = checked & (last != g) & (last != -1) & tracked_here & (prev != -1)
        frag_mid = checked & ~end & (prev != g) & (last != -1) & tracked_here & (nxt != -1)
        frag_last = checked & end & (prev != g) & tracked_here

        seg = np.cumsum(start) - 1
        n_seg = int(seg[-1]) + 1
        length = np.bincount(seg, minlength=n_seg)
        n_ign = np.bincount(seg, weights=ign, minlength=n_seg)
        matched = np.bincount(seg, weights=tracked_here, minlength=n_seg)
        tracked = np.bincount(seg, weights=(checked | start) & tracked_here, minlength=n_seg)
        counted = n_ign < length
        lost = counted & (matched == 0)
        ratio = tracked / np.maximum(length - n_ign, 1)
        mostly_tracked = counted & ~lost & (ratio > 0.8)
        mostly_lost = lost | (counted & ~lost & (ratio < 0.2))
        return (
            int(switch.sum()),
            int((frag_mid | frag_last).sum()),
            int(mostly_tracked.sum()),
            int(mostly_lost.sum()),
            int(counted.sum()),
        )


def recall_points(scores: F64, num_gt: int) -> list[tuple[float, float]]:
    """(threshold, recall) pairs from the unthresholded run's TP scores (at most 40)."""
    ordered = np.sort(scores)[::-1]
    n = len(ordered)
    points: list[tuple[float, float]] = []
    current = 0.0
    for i, score in enumerate(ordered.tolist()):
        left = (i + 1) / float(num_gt)
        right = (i + 2) / float(num_gt) if i < n - 1 else left
        if (right - current) < (current - left) and i < n - 1:
            continue
        points.append((score, current))
        current += 1 / float(RECALL_POINTS)
    return points[1:]


def _pct(num: float, den: float) -> float:
    return 100.0 * num / den if den else 0.0


def evaluate_problem(problem: Problem) -> dict[str, float]:
    """Every figure of one class, percentages as in the reference metrics.json."""
    ev = ClassEvaluation(problem)
    first = ev.run(NO_THRESHOLD)
    points = recall_points(first.tp_scores, first.tp + first.fn)
    s_sum = a_sum = p_sum = 0.0
    best_mota, best_threshold = 0.0, NO_THRESHOLD
    for threshold, recall in points:
        counts = ev.run(threshold)
        s_sum += counts.smota(recall)
        a_sum += counts.mota
        p_sum += counts.motp
        if counts.mota > best_mota:
            best_mota, best_threshold = counts.mota, threshold
    final = ev.run(best_threshold)
    boxes = kitti_boxes(problem, final.kept, final.matched)
    return {
        "sAMOTA": 100.0 * s_sum / RECALL_POINTS,
        "AMOTA": 100.0 * a_sum / RECALL_POINTS,
        "AMOTP": 100.0 * p_sum / RECALL_POINTS,
        "MOTA": 100.0 * final.mota,
        "MOTP": 100.0 * final.motp,
        "IDS": final.ids,
        "FRAG": final.frag,
        "FP": final.fp,
        "FN": final.fn,
        "TP": final.tp,
        "Recall": _pct(final.tp, final.tp + final.fn),
        "Precision": _pct(final.tp, final.tp + final.fp),
        "MT": _pct(final.mt, final.n_traj),
        "ML": _pct(final.ml, final.n_traj),
        **hota_figures(boxes),
        **identity_counts(boxes).figures(),
    }


def evaluate(
    results_dir: Path, labels_dir: Path, seqs: Sequence[str], classes: Sequence[str]
) -> dict[str, dict[str, float]]:
    """Score KITTI tracking result files (``results_dir/NNNN.txt``) against labels."""
    return {
        cls: evaluate_problem(build_problem(labels_dir, results_dir, seqs, cls)) for cls in classes
    }
