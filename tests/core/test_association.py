"""Assignment: optimal vs greedy, thresholds, and the order new tracks are born in."""

from __future__ import annotations

import numpy as np

from simpletrack.core.association import assign, greedy, hungarian
from simpletrack.core.config import Matcher


def test_hungarian_finds_the_global_optimum_where_greedy_does_not() -> None:
    dist = np.array([[0.1, 0.2], [0.15, 1.0]])
    h = hungarian(dist, 0.5)
    g = greedy(dist, 0.5)
    assert sorted(zip(h.det.tolist(), h.track.tolist(), strict=True)) == [(0, 1), (1, 0)]
    assert sorted(zip(g.det.tolist(), g.track.tolist(), strict=True)) == [(0, 0)]
    assert g.unmatched_dets.tolist() == [1] and g.unmatched_tracks.tolist() == [1]


def test_pairs_over_the_threshold_are_rejected() -> None:
    dist = np.array([[0.2, 1.9], [1.8, 1.7]])
    a = hungarian(dist, 1.5)
    assert a.det.tolist() == [0] and a.track.tolist() == [0]
    assert a.unmatched_dets.tolist() == [1] and a.unmatched_tracks.tolist() == [1]


def test_unmatched_order_is_unassigned_first_then_rejected() -> None:
    # 3 detections, 1 track: det 1 is assigned but over the threshold.
    dist = np.array([[1.9], [1.6], [1.95]])
    a = hungarian(dist, 1.5)
    assert a.unmatched_dets.tolist() == [0, 2, 1]


def test_empty_matrices() -> None:
    for m in (Matcher.HUNGARIAN, Matcher.GREEDY):
        for shape in [(0, 0), (0, 3), (3, 0)]:
            a = assign(np.zeros(shape), 1.5, m)
            assert a.det.size == 0
            assert a.unmatched_dets.tolist() == list(range(shape[0]))
            assert a.unmatched_tracks.tolist() == list(range(shape[1]))
