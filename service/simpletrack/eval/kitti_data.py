"""Inputs of the KITTI 3D MOT evaluation: label and result files, filtered for one class,
turned into flat arrays and the threshold-independent (ground truth, tracker) candidate pairs,
plus every overlapping pair (3D IoU > 0) for HOTA and IDF1 (``simpletrack.eval.hota``).

Rules: ../shared/spec/KITTI_EVAL.md (AB3DMOT's evaluator run as ``3D 0.25``).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import numpy.typing as npt

from simpletrack.eval.kitti_overlap import box2d_overlap_own_area, footprints_may_touch, iou3d_pairs

F64 = npt.NDArray[np.float64]
I64 = npt.NDArray[np.int64]
Bool = npt.NDArray[np.bool_]

IOU_THRESHOLD = 0.25
MAX_COST = 1.0 - IOU_THRESHOLD  # a pair matches only if 1 - IoU3D <= this
MAX_OCCLUSION = 2
MAX_TRUNCATION = 0
MIN_HEIGHT = 25.0  # pixels: smaller unmatched tracker boxes are not false positives
DONTCARE_OVERLAP = 0.5
NEIGHBOUR = {"car": "van", "pedestrian": "person_sitting", "cyclist": None}
DONTCARE = "dontcare"


@dataclass(frozen=True, slots=True)
class TrackingRows:
    """Rows of a KITTI tracking file (labels: 17 fields, results: 18 with the score).
    ``kind`` holds lower-case type names."""

    frame: I64
    track_id: I64
    kind: npt.NDArray[np.str_]
    truncation: F64
    occlusion: F64
    box2d: F64
    cam: F64  # h, w, l, x, y, z, rot_y
    score: F64

    def __len__(self) -> int:
        return int(self.frame.shape[0])

    def take(self, mask: Bool | I64) -> TrackingRows:
        return TrackingRows(
            self.frame[mask],
            self.track_id[mask],
            self.kind[mask],
            self.truncation[mask],
            self.occlusion[mask],
            self.box2d[mask],
            self.cam[mask],
            self.score[mask],
        )


def read_tracking_file(path: Path, with_score: bool) -> TrackingRows:
    """Parse ``frame id type trunc occ alpha x1 y1 x2 y2 h w l x y z rot_y [score]``."""
    need = 18 if with_score else 17
    head: list[tuple[int, int, str]] = []
    nums: list[list[float]] = []
    for lineno, line in enumerate(path.read_text().splitlines(), 1):
        f = line.split()
        if not f:
            continue
        if len(f) < need:
            raise ValueError(f"{path}:{lineno}: expected {need} fields, got {len(f)}")
        try:
            head.append((int(float(f[0])), int(float(f[1])), f[2].lower()))
            # float() of the text gives the same float64 the reference evaluator reads.
            nums.append([float(v) for v in f[3:need]])
        except ValueError:
            raise ValueError(f"{path}:{lineno}: not a number in {line.strip()!r}") from None
    n = len(head)
    v = np.array(nums, dtype=np.float64).reshape(n, need - 3)
    return TrackingRows(
        frame=np.array([h[0] for h in head], dtype=np.int64),
        track_id=np.array([h[1] for h in head], dtype=np.int64),
        kind=np.array([h[2] for h in head], dtype=np.str_),
        truncation=v[:, 0],
        occlusion=v[:, 1],
        box2d=v[:, 3:7],
        cam=v[:, 7:14],
        score=v[:, 14] if with_score else np.zeros(n),
    )


def class_filter(rows: TrackingRows, cls: str) -> Bool:
    """Rows the evaluator loads for ``cls``: the class, its neighbour, DontCare."""
    neighbour = NEIGHBOUR.get(cls)
    names = [cls, DONTCARE] + ([neighbour] if neighbour else [])
    return np.asarray(np.isin(rows.kind, names))


@dataclass(frozen=True, slots=True)
class Problem:
    """One class over all sequences. Frames are numbered globally (sequence offsets), tracks
    and ground-truth trajectories densely (0..n-1) across sequences."""

    gt_frame: I64
    gt_traj: I64
    gt_ignored: Bool
    n_traj: int
    trk_frame: I64
    trk_track: I64
    trk_ignorable: Bool  # not a false positive when unmatched
    trk_score: F64  # raw scores, as read
    n_tracks: int
    pair_gt: I64  # candidate pairs (IoU3D >= threshold), sorted by frame
    pair_trk: I64
    pair_cost: F64  # 1 - IoU3D
    segments: I64  # (S + 1,) bounds of each frame's run of pairs
    touch_gt: I64  # every same-frame pair with IoU3D > 0, sorted by frame (HOTA's similarity)
    touch_trk: I64
    touch_iou: F64


@dataclass(frozen=True, slots=True)
class _Seq:
    gt: TrackingRows
    dc: TrackingRows
    trk: TrackingRows
    n_frames: int


def _load_sequence(label_path: Path, result_path: Path, cls: str) -> _Seq:
    labels = read_tracking_file(label_path, with_score=False)
    n_frames = int(labels.frame.max(initial=-1)) + 1
    labels = labels.take(class_filter(labels, cls))
    results = read_tracking_file(result_path, with_score=True)
    results = results.take(class_filter(results, cls) & (results.track_id != -1))
    results = results.take(results.kind != DONTCARE)
    if len(results) and int(results.frame.max()) >= n_frames:
        raise ValueError(
            f"{result_path}: frame {int(results.frame.max())} is past the last labelled frame "
            f"{n_frames - 1}"
        )
    key = results.frame * (1 << 32) + results.track_id
    uniq, counts = np.unique(key, return_counts=True)
    if (counts > 1).any():
        dup = int(uniq[counts > 1][0])
        raise ValueError(
            f"{result_path}: track id {dup & 0xFFFFFFFF} appears twice in frame {dup >> 32} ({cls})"
        )
    is_dc = labels.kind == DONTCARE
    return _Seq(gt=labels.take(~is_dc), dc=labels.take(is_dc), trk=results, n_frames=n_frames)


def _same_frame_pairs(frame_a: I64, frame_b: I64) -> tuple[I64, I64]:
    """All (i, j) with frame_a[i] == frame_b[j]; both inputs sorted by frame."""
    if len(frame_a) == 0 or len(frame_b) == 0:
        return np.zeros(0, np.int64), np.zeros(0, np.int64)
    lo = np.searchsorted(frame_b, frame_a, side="left")
    hi = np.searchsorted(frame_b, frame_a, side="right")
    count = hi - lo
    i = np.repeat(np.arange(len(frame_a)), count)
    starts = np.repeat(lo - np.concatenate([[0], np.cumsum(count)[:-1]]), count)
    j = np.arange(len(i)) + starts
    return i.astype(np.int64), j.astype(np.int64)


def _tracker_ignorable(seq: _Seq, cls: str) -> Bool:
    trk = seq.trk
    neighbour = NEIGHBOUR.get(cls)
    ign = np.abs(trk.box2d[:, 3] - trk.box2d[:, 1]) <= MIN_HEIGHT
    if neighbour:
        ign |= trk.kind == neighbour
    ti, di = _same_frame_pairs(trk.frame, seq.dc.frame)
    over = box2d_overlap_own_area(trk.box2d[ti], seq.dc.box2d[di]) > DONTCARE_OVERLAP
    ign[ti[over]] = True
    return np.asarray(ign)


def _sorted_by_frame(rows: TrackingRows) -> TrackingRows:
    return rows.take(np.argsort(rows.frame, kind="stable"))


def build_problem(labels_dir: Path, results_dir: Path, seqs: Sequence[str], cls: str) -> Problem:
    """Load ``cls`` (case-insensitive) for every sequence and compute the candidate pairs."""
    cls = cls.lower()
    if cls not in NEIGHBOUR:
        raise ValueError(f"unknown KITTI class {cls!r}; choose from Car, Pedestrian, Cyclist")
    parts: dict[str, list[npt.NDArray[np.generic]]] = {
        k: []
        for k in (
            "gt_frame", "gt_traj", "gt_ign", "trk_frame", "trk_track", "trk_ign", "trk_score",
            "pair_gt", "pair_trk", "pair_cost", "touch_gt", "touch_trk", "touch_iou",
        )
    }  # fmt: skip
    frame_base = n_gt = n_trk = n_traj = n_tracks = 0
    for seq_name in seqs:
        result_path = results_dir / f"{seq_name}.txt"
        if not result_path.is_file():
            raise FileNotFoundError(f"no result file for sequence {seq_name}: {result_path}")
        seq = _load_sequence(labels_dir / f"{seq_name}.txt", result_path, cls)
        gt, trk = _sorted_by_frame(seq.gt), _sorted_by_frame(seq.trk)
        seq = _Seq(gt=gt, dc=_sorted_by_frame(seq.dc), trk=trk, n_frames=seq.n_frames)

        neighbour = NEIGHBOUR[cls]
        ign = (gt.occlusion > MAX_OCCLUSION) | (gt.truncation > MAX_TRUNCATION)
        if neighbour:
            ign |= gt.kind == neighbour
        _, traj = np.unique(gt.track_id, return_inverse=True)
        _, track = np.unique(trk.track_id, return_inverse=True)

        gi, ti = _same_frame_pairs(gt.frame, trk.frame)
        near = footprints_may_touch(gt.cam[gi], trk.cam[ti])
        gi, ti = gi[near], ti[near]
        iou = iou3d_pairs(gt.cam[gi], trk.cam[ti])
        cost = 1.0 - iou
        ok = cost <= MAX_COST
        touch = iou > 0.0

        parts["gt_frame"].append(gt.frame + frame_base)
        parts["gt_traj"].append(traj.reshape(-1) + n_traj)
        parts["gt_ign"].append(ign)
        parts["trk_frame"].append(trk.frame + frame_base)
        parts["trk_track"].append(track.reshape(-1) + n_tracks)
        parts["trk_ign"].append(_tracker_ignorable(seq, cls))
        parts["trk_score"].append(trk.score)
        parts["pair_gt"].append(gi[ok] + n_gt)
        parts["pair_trk"].append(ti[ok] + n_trk)
        parts["pair_cost"].append(cost[ok])
        parts["touch_gt"].append(gi[touch] + n_gt)
        parts["touch_trk"].append(ti[touch] + n_trk)
        parts["touch_iou"].append(iou[touch])
        frame_base += seq.n_frames
        n_gt += len(gt)
        n_trk += len(trk)
        n_traj += int(traj.max(initial=-1)) + 1
        n_tracks += int(track.max(initial=-1)) + 1

    cat = {k: np.concatenate(v) if v else np.zeros(0) for k, v in parts.items()}
    gt_frame = cat["gt_frame"].astype(np.int64)
    pair_gt = cat["pair_gt"].astype(np.int64)
    # Pairs come out ordered by ground-truth frame already; mark where each frame's run starts.
    pair_frame = gt_frame[pair_gt]
    starts = np.flatnonzero(np.diff(pair_frame, prepend=-1) != 0)
    return Problem(
        gt_frame=gt_frame,
        gt_traj=cat["gt_traj"].astype(np.int64),
        gt_ignored=cat["gt_ign"].astype(bool),
        n_traj=n_traj,
        trk_frame=cat["trk_frame"].astype(np.int64),
        trk_track=cat["trk_track"].astype(np.int64),
        trk_ignorable=cat["trk_ign"].astype(bool),
        trk_score=cat["trk_score"].astype(np.float64),
        n_tracks=n_tracks,
        pair_gt=pair_gt,
        pair_trk=cat["pair_trk"].astype(np.int64),
        pair_cost=cat["pair_cost"].astype(np.float64),
        segments=np.append(starts, len(pair_gt)).astype(np.int64),
        touch_gt=cat["touch_gt"].astype(np.int64),
        touch_trk=cat["touch_trk"].astype(np.int64),
        touch_iou=cat["touch_iou"].astype(np.float64),
    )
