"""The live MOTA/IDS scorer: every count on hand-made frames whose answer is known."""

from __future__ import annotations

import math

import numpy as np
import pytest

from simpletrack.core.boxes import Boxes
from simpletrack.eval.clear_mot import Matching, MotCounts, MotScorer


def boxes(*xy_cls: tuple[float, float, int]) -> Boxes:
    params = [[x, y, 0.8, 0.0, 4.0, 2.0, 1.6] for x, y, _ in xy_cls]
    return Boxes.from_arrays(
        np.array(params).reshape(-1, 7), np.ones(len(xy_cls)), [c for _, _, c in xy_cls]
    )


def test_perfect_tracking_scores_one() -> None:
    s = MotScorer()
    for k in range(5):
        s.update([1, 2], boxes((k, 0, 0), (k, 10, 1)), [7, 8], boxes((k + 0.1, 0, 0), (k, 10.2, 1)))
    c = s.counts
    assert (c.gt, c.tp, c.fp, c.fn, c.ids, c.frames) == (10, 10, 0, 0, 0, 5)
    assert c.mota == 1.0
    assert c.motp == pytest.approx(0.15)


def test_misses_false_positives_and_the_gate() -> None:
    s = MotScorer(max_distance=2.0)
    # Truth 1 tracked 1.5 m off (inside the gate); truth 2 missed; track 9 is 3 m off -> FP.
    f = s.update([1, 2], boxes((0, 0, 0), (50, 0, 0)), [5, 9], boxes((1.5, 0, 0), (53, 0, 0)))
    assert (f.tp, f.fn, f.fp, f.ids) == (1, 1, 1, 0)
    assert s.counts.mota == pytest.approx(1 - 2 / 2)


def test_class_gate_blocks_matches_across_classes() -> None:
    s = MotScorer()
    f = s.update([1], boxes((0, 0, 0)), [5], boxes((0, 0, 1)))
    assert (f.tp, f.fn, f.fp) == (0, 1, 1)


def test_an_id_switch_is_counted_once_and_survives_a_gap() -> None:
    s = MotScorer()
    s.update([1], boxes((0, 0, 0)), [5], boxes((0, 0, 0)))
    s.update([1], boxes((1, 0, 0)), [], Boxes.empty())  # missed: a gap, not a switch
    f = s.update([1], boxes((2, 0, 0)), [6], boxes((2, 0, 0)))  # new id after the gap
    assert f.ids == 1
    f = s.update([1], boxes((3, 0, 0)), [6], boxes((3, 0, 0)))
    assert f.ids == 0
    c = s.counts
    assert (c.gt, c.tp, c.fn, c.ids) == (4, 3, 1, 1)
    assert c.mota == pytest.approx(1 - (1 + 1) / 4)


def test_hungarian_picks_the_assignment_with_least_total_distance() -> None:
    s = MotScorer(max_distance=3.0)
    # Greedy would pair truth 1 with track 10 (0.9 m) first and leave truth 2 alone (track 11
    # is 4.5 m from it); the optimum pairs 1-11 (2.5 m) and 2-10 (1.1 m).
    truth = boxes((0, 0, 0), (2, 0, 0))
    tracks = boxes((0.9, 0, 0), (-2.5, 0, 0))
    f = s.update([1, 2], truth, [10, 11], tracks)
    assert (f.tp, f.fp, f.fn) == (2, 0, 0)


def test_ignored_truth_is_neither_miss_nor_false_positive() -> None:
    s = MotScorer()
    f = s.update(
        [1, 2], boxes((0, 0, 0), (20, 0, 0)), [5], boxes((20, 0, 0)), truth_ignore=[False, True]
    )
    assert (f.gt, f.tp, f.fn, f.fp, f.ignored) == (1, 0, 1, 0, 1)


def test_iou_matching_uses_3d_iou() -> None:
    s = MotScorer(matching=Matching.IOU_3D, min_iou=0.5)
    # A 4 m box shifted 1 m along its length overlaps 3/5 (IoU 0.6); shifted 2 m, 1/3.
    f = s.update([1, 2], boxes((0, 0, 0), (50, 0, 0)), [5, 6], boxes((1, 0, 0), (52, 0, 0)))
    assert (f.tp, f.fp, f.fn) == (1, 1, 1)
    assert s.counts.motp == pytest.approx(0.6)


def test_counts_add_across_streams_and_mota_is_nan_without_truth() -> None:
    a = MotCounts(frames=1, gt=4, tp=3, fp=1, fn=1, ids=0)
    b = MotCounts(frames=2, gt=6, tp=6, fp=0, fn=0, ids=1)
    total = a + b
    assert (total.frames, total.gt, total.ids) == (3, 10, 1)
    assert total.mota == pytest.approx(1 - 3 / 10)
    assert math.isnan(MotCounts().mota)


def test_memory_of_departed_truth_is_bounded() -> None:
    s = MotScorer(forget_after=10)
    for k in range(200):
        s.update([k], boxes((0, 0, 0)), [k], boxes((0, 0, 0)))
    assert len(s._last) <= 60


def test_ids_per_object_counts_distinct_track_ids_of_each_truth_object() -> None:
    s = MotScorer()
    # Truth 1: tracks 7, 8, then 7 again (2 distinct ids, 2 switches); truth 2: track 9 only.
    for tid in (7, 8, 7):
        s.update([1, 2], boxes((0, 0, 0), (20, 0, 0)), [tid, 9], boxes((0, 0, 0), (20, 0, 0)))
    c = s.counts
    assert (c.ids, c.objects, c.id_links) == (2, 2, 3)
    assert c.ids_per_object == pytest.approx(1.5)
    # Ignored matches say nothing about identity; no matched truth: NaN.
    t = MotScorer()
    t.update([3], boxes((0, 0, 0)), [4], boxes((0, 0, 0)), truth_ignore=[True])
    assert t.counts.objects == 0 and math.isnan(t.counts.ids_per_object)
