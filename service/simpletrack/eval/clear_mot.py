"""A small, exact CLEAR-MOT scorer (MOTA, MOTP, IDS) that runs live, one frame at a time.

Definitions (per frame, then summed):

- A ground-truth object and a track may match only if they have the same class and their
  distance passes the gate: centre distance (metres, 3D) <= ``max_distance`` for
  ``Matching.CENTRE``, or 3D IoU >= ``min_iou`` for ``Matching.IOU_3D``.
- The matching is the Hungarian assignment minimising the summed cost (distance, or 1 - IoU)
  over the pairs that pass the gate; it is recomputed from scratch every frame.
- Ground truth may be flagged *ignored* (e.g. mostly hidden): unmatched it is not a miss,
  matched its track is not a false positive; either way it is not counted in ``gt``.
- TP = matches to non-ignored truth; FN = unmatched non-ignored truth; FP = unmatched tracks.
- IDS: a non-ignored match whose track id differs from the track id that truth object was last
  matched to (in any earlier frame, ignored or not). A truth object's memory is forgotten after
  ``forget_after`` frames unseen, which bounds the scorer's state.
- MOTA = 1 - (FN + FP + IDS) / gt; MOTP = mean centre distance (or mean IoU) over the TPs.
- Ids per object: the distinct track ids each truth object was matched to (non-ignored
  matches), averaged over the truth objects matched at least once; 1.0 is a perfect tracker.
  A truth object forgotten (above) and seen again counts as a new object.
- Doubled: a non-ignored match whose truth object also has an unmatched track of its class
  within the gate (the object carries two ids at the same time); counted per frame.

Ids only need to be unique within one scorer: use one scorer per track stream, and add the
``MotCounts`` of several scorers for a fleet-wide figure.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from enum import StrEnum

import numpy as np
import numpy.typing as npt

from simpletrack.core.boxes import Boxes
from simpletrack.core.geometry import iou_3d
from simpletrack.core.solvers import linear_sum_assignment

F64 = npt.NDArray[np.float64]

_INVALID = 1e9


class Matching(StrEnum):
    CENTRE = "centre"
    IOU_3D = "iou_3d"


@dataclass(slots=True)
class MotCounts:
    """Summed CLEAR-MOT counts. ``+`` combines streams."""

    frames: int = 0
    gt: int = 0
    tp: int = 0
    fp: int = 0
    fn: int = 0
    ids: int = 0
    ignored: int = 0
    match_quality: float = 0.0  # summed distance (CENTRE) or IoU (IOU_3D) over TPs
    objects: int = 0  # distinct truth objects matched (non-ignored)
    id_links: int = 0  # distinct (truth object, track id) pairs among those matches
    doubled: int = 0  # matches whose truth object has a second track in the gate

    def __add__(self, other: MotCounts) -> MotCounts:
        return MotCounts(
            frames=self.frames + other.frames,
            gt=self.gt + other.gt,
            tp=self.tp + other.tp,
            fp=self.fp + other.fp,
            fn=self.fn + other.fn,
            ids=self.ids + other.ids,
            ignored=self.ignored + other.ignored,
            match_quality=self.match_quality + other.match_quality,
            objects=self.objects + other.objects,
            id_links=self.id_links + other.id_links,
            doubled=self.doubled + other.doubled,
        )

    @property
    def mota(self) -> float:
        """1 - (FN + FP + IDS) / GT; NaN before any ground truth was seen."""
        if self.gt == 0:
            return float("nan")
        return 1.0 - (self.fn + self.fp + self.ids) / self.gt

    @property
    def motp(self) -> float:
        return self.match_quality / self.tp if self.tp else float("nan")

    @property
    def ids_per_object(self) -> float:
        return self.id_links / self.objects if self.objects else float("nan")

    @property
    def doubled_share(self) -> float:
        """Of the matched truth boxes, the share that carried a second track at once."""
        return self.doubled / self.tp if self.tp else float("nan")

    @property
    def recall(self) -> float:
        return self.tp / self.gt if self.gt else float("nan")

    @property
    def precision(self) -> float:
        return self.tp / (self.tp + self.fp) if self.tp + self.fp else float("nan")


@dataclass(slots=True)
class _Memory:
    track_id: int
    last_frame: int


@dataclass
class MotScorer:
    """Scores one track stream against ground truth, frame by frame (see module docstring)."""

    matching: Matching = Matching.CENTRE
    max_distance: float = 2.0
    min_iou: float = 0.25
    forget_after: int = 100
    counts: MotCounts = field(default_factory=MotCounts)
    _last: dict[int, _Memory] = field(default_factory=dict)
    _links: dict[int, set[int]] = field(default_factory=dict)  # truth id -> its track ids

    def update(
        self,
        truth_ids: npt.ArrayLike,
        truth: Boxes,
        track_ids: npt.ArrayLike,
        tracks: Boxes,
        truth_ignore: npt.ArrayLike | None = None,
    ) -> MotCounts:
        """Score one frame; returns that frame's counts (also added to ``self.counts``).
        ``truth`` and ``tracks`` must be in the same coordinate frame."""
        gids = np.asarray(truth_ids, dtype=np.int64).reshape(-1)
        tids = np.asarray(track_ids, dtype=np.int64).reshape(-1)
        if gids.shape[0] != len(truth) or tids.shape[0] != len(tracks):
            raise ValueError(
                f"ids and boxes differ in length: truth {gids.shape[0]} vs {len(truth)}, "
                f"tracks {tids.shape[0]} vs {len(tracks)}"
            )
        ignore = (
            np.zeros(len(truth), dtype=bool)
            if truth_ignore is None
            else np.asarray(truth_ignore, dtype=bool).reshape(-1)
        )
        frame = self.counts.frames
        cost, quality = self._cost(truth, tracks)
        rows, cols = linear_sum_assignment(cost) if cost.size else (np.zeros(0, int),) * 2
        ok = cost[rows, cols] < _INVALID
        rows, cols = rows[ok], cols[ok]

        counted = ~ignore[rows]
        out = MotCounts(frames=1)
        out.gt = int((~ignore).sum())
        out.ignored = int(ignore.sum())
        out.tp = int(counted.sum())
        out.fn = out.gt - out.tp
        out.fp = len(tracks) - rows.shape[0]
        out.match_quality = float(quality[rows[counted], cols[counted]].sum())
        if cost.size:
            free = np.ones(len(tracks), dtype=bool)
            free[cols] = False
            near_free = (cost[rows[counted]][:, free] < _INVALID).any(axis=1)
            out.doubled = int(near_free.sum())
        for g, t, c in zip(gids[rows].tolist(), tids[cols].tolist(), counted.tolist(), strict=True):
            memory = self._last.get(g)
            if c and memory is not None and memory.track_id != t:
                out.ids += 1
            if c:
                links = self._links.setdefault(g, set())
                out.objects += not links
                out.id_links += t not in links
                links.add(t)
            self._last[g] = _Memory(t, frame)
        for g in gids.tolist():
            if g in self._last:
                self._last[g].last_frame = frame
        if frame % 50 == 0:
            self._forget(frame)
        self.counts = self.counts + out
        return out

    def _cost(self, truth: Boxes, tracks: Boxes) -> tuple[F64, F64]:
        same = truth.cls[:, None] == tracks.cls[None, :]
        if self.matching is Matching.CENTRE:
            d = np.linalg.norm(truth.params[:, None, :3] - tracks.params[None, :, :3], axis=2)
            gate = same & (d <= self.max_distance)
            return np.where(gate, d, _INVALID), d
        iou = iou_3d(truth.params, tracks.params)
        gate = same & (iou >= self.min_iou)
        return np.where(gate, 1.0 - iou, _INVALID), iou

    def _forget(self, frame: int) -> None:
        stale = [g for g, m in self._last.items() if frame - m.last_frame > self.forget_after]
        for g in stale:
            del self._last[g]
            self._links.pop(g, None)
