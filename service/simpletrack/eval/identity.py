"""IDF1, IDP, IDR of one class, as TrackEval's identity metric (``trackeval/metrics/identity.py``)
computes them, on the boxes ``simpletrack.eval.hota.kitti_boxes`` keeps.

Over the whole problem, a (gt id, tracker id) combination scores one per box pair of theirs
whose similarity reaches the threshold (every such pair of a frame, not only a one-to-one
matching, as TrackEval counts); the bipartite matching of gt ids to tracker ids with the
largest total score gives IDTP, and IDFN, IDFP are the gt and tracker boxes left. TrackEval
matches 2D boxes at IoU >= 0.5; this uses 3D IoU at the KITTI 3D threshold, 0.25. Sequences
are one problem with ids distinct across them: the same as summing IDTP, IDFN, IDFP per
sequence, which is how TrackEval combines sequences.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from simpletrack.core.solvers import linear_sum_assignment
from simpletrack.eval.hota import Boxes, id_links
from simpletrack.eval.kitti_data import IOU_THRESHOLD


@dataclass(frozen=True, slots=True)
class IdentityCounts:
    idtp: int
    idfn: int
    idfp: int

    def figures(self) -> dict[str, float]:
        """IDF1, IDP, IDR in percent (TrackEval's max(1, ...) denominators)."""
        tp, fn, fp = self.idtp, self.idfn, self.idfp
        return {
            "IDF1": 100.0 * tp / max(1.0, tp + 0.5 * fp + 0.5 * fn),
            "IDP": 100.0 * tp / max(1.0, tp + fp),
            "IDR": 100.0 * tp / max(1.0, tp + fn),
        }


def identity_counts(b: Boxes, threshold: float = IOU_THRESHOLD) -> IdentityCounts:
    close = b.pair_sim >= threshold
    links = id_links(b, close)
    potential = np.bincount(links.link, minlength=len(links.gt)).astype(np.float64)
    # Only ids that overlap somewhere can be matched with a gain: solve over those alone.
    rows, ri = np.unique(links.gt, return_inverse=True)
    cols, ci = np.unique(links.trk, return_inverse=True)
    mat = np.zeros((len(rows), len(cols)))
    mat[ri, ci] = potential
    r, c = linear_sum_assignment(mat, maximize=True)
    idtp = round(float(mat[r, c].sum()))
    return IdentityCounts(idtp=idtp, idfn=len(b.gt_id) - idtp, idfp=len(b.trk_id) - idtp)
