"""HOTA (DetA, AssA, LocA) of one class, as TrackEval defines it (``trackeval/metrics/hota.py``),
with 3D IoU as the similarity, and the KITTI boxes it is computed on.

Which boxes (``kitti_boxes``), from the KITTI evaluator's final run, the one at the best-MOTA
score threshold that gives MOTA, IDS, FP, FN (``simpletrack.eval.kitti``):

- ground truth: the boxes that MOTA counts (its ``n_gt``): the class itself, not occluded past
  2, not truncated. Neighbour-class boxes (Van for Car, Person_sitting for Pedestrian),
  occluded and truncated ones and DontCare regions are removed, matched or not.
- tracker boxes: those of tracks whose mean score reaches that threshold, minus the ones that
  run matched (3D IoU >= 0.25, Hungarian) to a removed ground-truth box, minus the unmatched
  ones it ignores (2D height <= 25 px, more than half inside a DontCare box, or typed as the
  neighbour class). What is left is exactly what MOTA counts as true or false positives.

This is TrackEval's KITTI preprocessing (match, drop tracker boxes on distractors, drop
unmatched small or DontCare ones, drop distractor ground truth) with the evaluator's own
matching in place of TrackEval's separate 2D IoU >= 0.5 one; TrackEval never loads
neighbour-typed tracker boxes, here one matched to a counted car stays (MOTA counts it), and
Cyclist, which TrackEval's KITTI does not evaluate, has no distractor class.

HOTA itself follows TrackEval line for line: per frame, each pair's share of its rows' and
columns' similarity sums adds to its (gt id, tracker id) potential matches; their Jaccard
with the ids' box counts is the global alignment score; per frame one Hungarian assignment
maximises alignment x similarity, and at each alpha in 0.05:0.05:0.95 its pairs with
similarity >= alpha are the true positives. Sequences are one problem with ids distinct
across them, which sums the per-alpha counts and weights AssA and LocA by true positives, as
TrackEval combines sequences. Figures are means over the alphas, in percent; at an alpha
with no true positive LocA is 1 (TrackEval's 1e-10 / 1e-10).
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from simpletrack.core.solvers import linear_sum_assignment
from simpletrack.eval.kitti_data import Problem

F64 = npt.NDArray[np.float64]
I64 = npt.NDArray[np.int64]
Bool = npt.NDArray[np.bool_]

ALPHAS = np.arange(0.05, 0.99, 0.05)  # TrackEval's array_labels, float steps and all
_EPS = float(np.finfo(float).eps)


@dataclass(frozen=True, slots=True)
class Boxes:
    """The boxes scored, by id and frame, and their overlapping same-frame pairs."""

    gt_frame: I64
    gt_id: I64  # dense 0..n_gt_ids-1
    trk_frame: I64
    trk_id: I64  # dense 0..n_trk_ids-1
    pair_gt: I64  # every pair with similarity > 0, sorted by frame
    pair_trk: I64
    pair_sim: F64
    n_gt_ids: int
    n_trk_ids: int


def _dense(labels: I64) -> tuple[I64, int]:
    uniq, inv = np.unique(labels, return_inverse=True)
    return inv.reshape(-1).astype(np.int64), len(uniq)


def kitti_boxes(problem: Problem, kept: Bool, matched: I64) -> Boxes:
    """The boxes HOTA and IDF1 score (module docstring), from one evaluator run: ``kept`` are
    its tracker boxes above the threshold, ``matched`` its matched candidate pairs."""
    p = problem
    gt_keep = ~p.gt_ignored
    on_ignored = p.pair_trk[matched][p.gt_ignored[p.pair_gt[matched]]]
    was_matched = np.zeros(len(p.trk_frame), dtype=bool)
    was_matched[p.pair_trk[matched]] = True
    trk_keep = kept & ~(~was_matched & p.trk_ignorable)
    trk_keep[on_ignored] = False

    gt_new = np.cumsum(gt_keep) - 1
    trk_new = np.cumsum(trk_keep) - 1
    both = gt_keep[p.touch_gt] & trk_keep[p.touch_trk]
    gt_id, n_gt_ids = _dense(p.gt_traj[gt_keep])
    trk_id, n_trk_ids = _dense(p.trk_track[trk_keep])
    return Boxes(
        gt_frame=p.gt_frame[gt_keep],
        gt_id=gt_id,
        trk_frame=p.trk_frame[trk_keep],
        trk_id=trk_id,
        pair_gt=gt_new[p.touch_gt[both]].astype(np.int64),
        pair_trk=trk_new[p.touch_trk[both]].astype(np.int64),
        pair_sim=p.touch_iou[both],
        n_gt_ids=n_gt_ids,
        n_trk_ids=n_trk_ids,
    )


@dataclass(frozen=True, slots=True)
class IdLinks:
    """The (gt id, tracker id) combinations that overlap somewhere: ``link[k]`` of pair k."""

    link: I64
    gt: I64  # per link: its gt id and tracker id
    trk: I64


def id_links(b: Boxes, pairs: Bool | I64 | slice = slice(None)) -> IdLinks:
    key = b.gt_id[b.pair_gt[pairs]] * max(b.n_trk_ids, 1) + b.trk_id[b.pair_trk[pairs]]
    uniq, link = np.unique(key, return_inverse=True)
    n = max(b.n_trk_ids, 1)
    return IdLinks(link.reshape(-1).astype(np.int64), uniq // n, uniq % n)


def _frame_assignment(b: Boxes, score: F64) -> I64:
    """Indices of the pairs one Hungarian assignment per frame keeps, maximising ``score``."""
    per_gt = np.bincount(b.pair_gt, minlength=len(b.gt_id))[b.pair_gt]
    per_trk = np.bincount(b.pair_trk, minlength=len(b.trk_id))[b.pair_trk]
    alone = (per_gt == 1) & (per_trk == 1)  # a pair that competes with none always matches
    chosen = [np.flatnonzero(alone)]
    rest = np.flatnonzero(~alone)
    frame = b.gt_frame[b.pair_gt[rest]]
    bounds = np.flatnonzero(np.diff(frame, prepend=-1, append=-1) != 0)
    for lo, hi in itertools.pairwise(bounds):
        idx = rest[lo:hi]
        rows, ri = np.unique(b.pair_gt[idx], return_inverse=True)
        cols, ci = np.unique(b.pair_trk[idx], return_inverse=True)
        mat = np.zeros((len(rows), len(cols)))
        mat[ri, ci] = score[idx]
        which = np.full((len(rows), len(cols)), -1, dtype=np.int64)
        which[ri, ci] = idx
        r, c = linear_sum_assignment(mat, maximize=True)
        picked = which[r, c]
        chosen.append(picked[picked >= 0])
    return np.sort(np.concatenate(chosen)).astype(np.int64)


@dataclass(frozen=True, slots=True)
class HotaCounts:
    """Per alpha: TrackEval's HOTA_TP, HOTA_FN, HOTA_FP and the derived figures (fractions)."""

    tp: F64
    fn: F64
    fp: F64
    ass_a: F64
    loc_a: F64

    @property
    def det_a(self) -> F64:
        return np.asarray(self.tp / np.maximum(1.0, self.tp + self.fn + self.fp))

    @property
    def hota(self) -> F64:
        return np.asarray(np.sqrt(self.det_a * self.ass_a))


def hota_counts(b: Boxes) -> HotaCounts:
    gi, ti, sim = b.pair_gt, b.pair_trk, b.pair_sim
    gt_count = np.bincount(b.gt_id, minlength=b.n_gt_ids).astype(np.float64)
    trk_count = np.bincount(b.trk_id, minlength=b.n_trk_ids).astype(np.float64)
    links = id_links(b)

    # Each pair's similarity over its row's and column's (a soft IoU of the two boxes' matches).
    row = np.bincount(gi, weights=sim, minlength=len(b.gt_id))
    col = np.bincount(ti, weights=sim, minlength=len(b.trk_id))
    denom = row[gi] + col[ti] - sim
    ok = denom > _EPS
    share = np.where(ok, sim / np.where(ok, denom, 1.0), 0.0)
    potential = np.bincount(links.link, weights=share, minlength=len(links.gt))
    link_boxes = gt_count[links.gt] + trk_count[links.trk]
    alignment = potential / (link_boxes - potential)

    matched = _frame_assignment(b, alignment[links.link] * sim)
    hit = sim[matched][:, None] >= ALPHAS[None, :] - _EPS  # (matches, alphas)
    tp = hit.sum(axis=0).astype(np.float64)
    loc_sum = (sim[matched][:, None] * hit).sum(axis=0)
    counts = np.zeros((len(links.gt), len(ALPHAS)))
    np.add.at(counts, links.link[matched], hit.astype(np.float64))
    ass = counts / np.maximum(1.0, link_boxes[:, None] - counts)
    return HotaCounts(
        tp=tp,
        fn=len(b.gt_id) - tp,
        fp=len(b.trk_id) - tp,
        ass_a=(counts * ass).sum(axis=0) / np.maximum(1.0, tp),
        loc_a=np.maximum(1e-10, loc_sum) / np.maximum(1e-10, tp),
    )


def hota_figures(b: Boxes) -> dict[str, float]:
    """HOTA, DetA, AssA, LocA in percent: means over the alphas, as TrackEval reports them."""
    c = hota_counts(b)
    return {
        "HOTA": 100.0 * float(c.hota.mean()),
        "DetA": 100.0 * float(c.det_a.mean()),
        "AssA": 100.0 * float(c.ass_a.mean()),
        "LocA": 100.0 * float(c.loc_a.mean()),
    }
