"""Parity of two tracker outputs: one taken as ground truth, boxes matched by centre distance.

Used to compare our nuScenes output with the reference tracker's (1 cm match): CLEAR-MOT
MOTA and identity switches, per class and overall, frame by frame with Hungarian matching.
"""

from __future__ import annotations

from collections import defaultdict
from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from simpletrack.core.solvers import linear_sum_assignment

Key = tuple[str, str, int]  # scene, class, frame


@dataclass
class ParityCounts:
    truth: int = 0
    matches: int = 0
    fp: int = 0
    fn: int = 0
    ids: int = 0

    @property
    def mota(self) -> float:
        return 1.0 - (self.fn + self.fp + self.ids) / self.truth if self.truth else 1.0

    @property
    def ids_ratio(self) -> float:
        return self.ids / self.matches if self.matches else 0.0

    def as_dict(self) -> dict[str, Any]:
        return {
            "truth": self.truth,
            "matches": self.matches,
            "fp": self.fp,
            "fn": self.fn,
            "ids": self.ids,
            "mota": round(self.mota, 6),
            "ids_per_match": round(self.ids_ratio, 6),
        }


@dataclass
class ParityReport:
    overall: ParityCounts = field(default_factory=ParityCounts)
    per_class: dict[str, ParityCounts] = field(default_factory=lambda: defaultdict(ParityCounts))
    per_scene: dict[str, ParityCounts] = field(default_factory=lambda: defaultdict(ParityCounts))

    def as_dict(self) -> dict[str, Any]:
        worst = sorted(self.per_scene.items(), key=lambda kv: kv[1].mota)
        return {
            "overall": self.overall.as_dict(),
            "per_class": {k: v.as_dict() for k, v in sorted(self.per_class.items())},
            "scenes": len(self.per_scene),
            "worst_scenes": {k: v.as_dict() for k, v in worst[:5]},
        }


def group_rows(rows: Iterable[Mapping[str, Any]]) -> dict[Key, tuple[np.ndarray, np.ndarray]]:
    """JSON-line rows → {(scene, cls, frame): (ids (K,), centres (K, 3))}."""
    acc: dict[Key, tuple[list[int], list[list[float]]]] = defaultdict(lambda: ([], []))
    for r in rows:
        ids, xyz = acc[(str(r["scene"]), str(r["cls"]), int(r["frame"]))]
        ids.append(int(r["id"]))
        xyz.append([float(v) for v in r["box"][:3]])
    return {
        k: (np.array(i, dtype=np.int64), np.array(c, dtype=np.float64).reshape(-1, 3))
        for k, (i, c) in acc.items()
    }


def compare(
    truth: Mapping[Key, tuple[np.ndarray, np.ndarray]],
    ours: Mapping[Key, tuple[np.ndarray, np.ndarray]],
    max_distance: float = 0.01,
) -> ParityReport:
    report = ParityReport()
    last: dict[tuple[str, str, int], int] = {}  # (scene, cls, truth id) -> our id last matched
    empty = (np.zeros(0, dtype=np.int64), np.zeros((0, 3)))
    for key in sorted(set(truth) | set(ours)):
        scene, cls, _ = key
        t_ids, t_xyz = truth.get(key, empty)
        o_ids, o_xyz = ours.get(key, empty)
        counts = report.per_class[cls]
        dist = np.linalg.norm(t_xyz[:, None, :] - o_xyz[None, :, :], axis=2)
        rows, cols = linear_sum_assignment(dist) if dist.size else (np.zeros(0, int),) * 2
        ok = dist[rows, cols] <= max_distance + 1e-9
        rows, cols = rows[ok], cols[ok]
        ids = 0
        for r, c in zip(rows.tolist(), cols.tolist(), strict=True):
            k = (scene, cls, int(t_ids[r]))
            prev = last.get(k)
            if prev is not None and prev != int(o_ids[c]):
                ids += 1
            last[k] = int(o_ids[c])
        for c_ in (counts, report.overall, report.per_scene[scene]):
            c_.truth += len(t_ids)
            c_.matches += len(rows)
            c_.fn += len(t_ids) - len(rows)
            c_.fp += len(o_ids) - len(rows)
            c_.ids += ids
    return report
