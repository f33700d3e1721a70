"""The exact gates (core/gate.py) never drop a pair the exact distance lets pass, and a gated
frame (core/pairs.py) gives the dense frame's result wherever the proof says it must."""

from __future__ import annotations

import tracemalloc

import numpy as np
import numpy.typing as npt
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.optimize import linear_sum_assignment

import simpletrack.core.tracker as tracker_module
from simpletrack.bench.heavy import heavy_scene
from simpletrack.core.association import hungarian, sparse_hungarian
from simpletrack.core.boxes import Boxes
from simpletrack.core.config import (
    ClassConfig,
    Matcher,
    Metric,
    OutputPolicy,
    TrackerConfig,
    VerticalOverlap,
    preset,
)
from simpletrack.core.frames import Frame, Tracks
from simpletrack.core.gate import association_pairs
from simpletrack.core.geometry import distance_matrix, iou_3d, iou_3d_pairs

F64 = npt.NDArray[np.float64]
I64 = npt.NDArray[np.int64]
# Thresholds near the metrics' ranges are the hard cases for the bounds.
THRESHOLDS = {
    Metric.GIOU_3D: (0.3, 1.99),
    Metric.GIOU_BEV: (0.3, 1.99),
    Metric.IOU_3D: (0.05, 0.999),
    Metric.IOU_BEV: (0.05, 0.999),
    Metric.L2: (0.1, 12.0),
    Metric.MAHALANOBIS: (0.5, 15.0),
}


def random_boxes(rng: np.random.Generator, n: int, spread: float) -> F64:
    """Boxes from slivers to buses, or all of one size (pairs right at the largest reach),
    some stacked on one spot, all yaws and heights."""
    xy = rng.uniform(-spread, spread, (n, 2))
    stack = rng.random(n) < 0.2
    xy[stack] = xy[0]
    if rng.random() < 0.5:
        size = np.tile(rng.uniform(0.3, 6.0, 3), (n, 1))
    else:
        size = rng.uniform(0.05, 12.0, (n, 3))
        size[rng.random(n) < 0.5] *= 0.1
    return np.column_stack([xy, rng.uniform(-3, 3, n), rng.uniform(-np.pi, np.pi, n), size]).astype(
        np.float64
    )


def random_innovation(rng: np.random.Generator, m: int) -> F64:
    a = rng.normal(0.0, rng.uniform(0.1, 5.0), (m, 7, 7))
    return np.asarray(a @ a.transpose(0, 2, 1) + np.eye(7), dtype=np.float64)


@settings(max_examples=120, deadline=None)
@given(
    seed=st.integers(0, 2**32 - 1),
    metric=st.sampled_from(list(Metric)),
    vertical=st.sampled_from(list(VerticalOverlap)),
    spread=st.sampled_from([1.0, 10.0, 40.0]),
    where=st.floats(0.0, 1.0),
)
def test_gate_never_drops_a_pair_within_the_threshold(
    seed: int, metric: Metric, vertical: VerticalOverlap, spread: float, where: float
) -> None:
    rng = np.random.default_rng(seed)
    n, m = int(rng.integers(1, 40)), int(rng.integers(1, 40))
    dets, preds = random_boxes(rng, n, spread), random_boxes(rng, m, spread)
    dg, pg = rng.integers(0, 3, n), rng.integers(0, 3, m)
    lo, hi = THRESHOLDS[metric]
    thr = lo + (hi - lo) * np.array([where, rng.random(), 1.0 - where])
    innovation = random_innovation(rng, m) if metric is Metric.MAHALANOBIS else None
    dist = distance_matrix(metric, dets, preds, vertical=vertical, innovation=innovation)
    must = (dist <= thr[dg][:, None]) & (dg[:, None] == pg[None, :])
    ia, ib = association_pairs(
        metric, dets, dg, preds, pg, thr, vertical=vertical, innovation=innovation
    )
    kept = np.zeros((n, m), dtype=bool)
    kept[ia, ib] = True
    assert not (must & ~kept).any(), np.argwhere(must & ~kept)[:3]
    assert (dg[ia] == pg[ib]).all()
    assert np.all(np.diff(ia * m + ib) > 0)  # row-major, no repeats


def test_gate_lists_far_fewer_pairs_than_all_on_a_street_scene() -> None:
    boxes = heavy_scene(3000).second.boxes
    cls = boxes.cls.astype(np.int64)
    ia, _ = association_pairs(Metric.GIOU_3D, boxes.params, cls, boxes.params, cls, np.full(7, 1.5))
    same_class = int(sum(int(c) ** 2 for c in np.bincount(cls)))
    assert ia.size < same_class / 10


@settings(max_examples=60, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), spread=st.sampled_from([0.5, 5.0, 50.0, 5e4]))
def test_grid_nms_pairs_are_every_overlapping_same_class_pair(seed: int, spread: float) -> None:
    rng = np.random.default_rng(seed)
    p = random_boxes(rng, int(rng.integers(190, 400)), spread)  # over the all-pairs cutoff
    p[:, :2] += 1e6  # far from the origin: cell keys must stay exact
    cls = rng.integers(0, 4, len(p))
    rows, cols, iou = iou_3d_pairs(p, p, groups_a=cls, groups_b=cls)
    dense = iou_3d(p, p) * (cls[:, None] == cls[None, :])
    listed = np.zeros_like(dense)
    listed[rows, cols] = iou
    np.testing.assert_array_equal(listed, dense)


# ---------------------------------------------------------------- assignment
def _k_filled(rows: I64, cols: I64, d: F64, shape: tuple[int, int], k: float) -> F64:
    full = np.full(shape, k)
    full[rows, cols] = d
    return full


@settings(max_examples=150, deadline=None)
@given(seed=st.integers(0, 2**32 - 1))
def test_sparse_hungarian_is_the_dense_optimum_with_unlisted_pairs_at_far_cost(
    seed: int,
) -> None:
    rng = np.random.default_rng(seed)
    n, m = int(rng.integers(1, 25)), int(rng.integers(1, 25))
    listed = rng.random((n, m)) < rng.uniform(0.02, 0.6)
    rows, cols = np.nonzero(listed)
    d = rng.uniform(0.0, 1.5, rows.size)
    k = 2.0
    full = _k_filled(rows, cols, d, (n, m), k)
    r, c = linear_sum_assignment(full)
    real = full[r, c] <= 1.5
    a = sparse_hungarian(rows, cols, d, n, m, k)
    assert set(zip(a.det.tolist(), a.track.tolist(), strict=True)) == set(
        zip(r[real].tolist(), c[real].tolist(), strict=True)
    )
    assert sorted(a.unmatched_dets.tolist()) == sorted(set(range(n)) - set(r[real].tolist()))
    assert a.unmatched_tracks.tolist() == sorted(set(range(m)) - set(c[real].tolist()))


def test_hungarian_optimum_depends_on_pairs_beyond_the_threshold() -> None:
    """Why core/pairs.py solves small blocks dense: the documented counter-example."""
    dense = np.array([[1.0, 1.51], [1.4, 1.99]])
    full = hungarian(dense, 1.5)
    assert (full.det.tolist(), full.track.tolist()) == ([1], [0])
    rows, cols = np.nonzero(dense <= 1.5)
    gated = sparse_hungarian(rows, cols, dense[rows, cols], 2, 2, 2.0)
    assert (gated.det.tolist(), gated.track.tolist()) == ([0], [0])


# ---------------------------------------------------------------- whole frames
def _stream(seed: int, frames: int, n: int) -> list[Frame]:
    rng = np.random.default_rng(seed)
    base = random_boxes(rng, n, 30.0)
    base[:, 4:] = rng.uniform(0.5, 5.0, (n, 3))
    cls = rng.integers(0, 2, n).astype(np.int32)
    out = []
    for k in range(frames):
        p = base.copy()
        p[:, :2] += rng.normal(0.0, 0.6, (n, 2)) + k * 0.5
        keep = rng.random(n) < 0.85
        score = rng.uniform(0.05, 1.0, n)
        out.append(Frame(boxes=Boxes.from_arrays(p[keep], score[keep], cls[keep]), stamp=k * 0.5))
    return out


def _run(config: TrackerConfig, frames: list[Frame]) -> list[Tracks]:
    tracker = tracker_module.Tracker(config)
    return [tracker.step(f) for f in frames]


def _same(a: list[Tracks], b: list[Tracks]) -> None:
    for x, y in zip(a, b, strict=True):
        np.testing.assert_array_equal(x.ids, y.ids)
        np.testing.assert_array_equal(x.boxes.params, y.boxes.params)
        np.testing.assert_array_equal(x.boxes.score, y.boxes.score)
        np.testing.assert_array_equal(x.update, y.update)
        np.testing.assert_array_equal(x.state, y.state)


@settings(max_examples=40, deadline=None)
@given(
    seed=st.integers(0, 2**32 - 1),
    metric=st.sampled_from(list(Metric)),
    vertical=st.sampled_from(list(VerticalOverlap)),
    two_stage=st.booleans(),
)
def test_gated_greedy_frames_equal_dense_frames(
    seed: int, metric: Metric, vertical: VerticalOverlap, two_stage: bool
) -> None:
    """Greedy and stage 2 read only pairs within their thresholds: gating changes nothing."""
    lo, hi = THRESHOLDS[metric]
    c = ClassConfig(
        score_high=0.4,
        score_low=0.1,
        two_stage=two_stage,
        metric=metric,
        matcher=Matcher.GREEDY,
        max_distance=(lo + hi) / 2,
        stage2_max_distance=lo + (hi - lo) / 4,
        min_hits=1,
    )
    config = TrackerConfig(
        classes={"a": c, "b": c}, output=OutputPolicy.NUSCENES, vertical_overlap=vertical
    )
    frames = _stream(seed, 4, 30)
    patch = pytest.MonkeyPatch()
    try:
        patch.setattr(tracker_module, "DENSE_CELLS", 0)
        gated = _run(config, frames)
        patch.setattr(tracker_module, "DENSE_CELLS", 1 << 40)
        dense = _run(config, frames)
    finally:
        patch.undo()
    _same(gated, dense)


@settings(max_examples=40, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), metric=st.sampled_from(list(Metric)))
def test_hungarian_frames_under_the_dense_cap_are_solved_on_the_full_matrix(
    seed: int, metric: Metric
) -> None:
    """Under DENSE_CELLS the result is the dense solve's, whatever the gate would list."""
    lo, hi = THRESHOLDS[metric]
    c = ClassConfig(score_high=0.3, metric=metric, max_distance=(lo + hi) / 2, min_hits=1)
    config = TrackerConfig(classes={"a": c, "b": c}, output=OutputPolicy.NUSCENES)
    frames = _stream(seed, 4, 30)
    reference = _run(config, frames)  # default cap: these blocks are far under it
    patch = pytest.MonkeyPatch()
    try:
        patch.setattr(tracker_module, "DENSE_CELLS", 1 << 40)
        _same(_run(config, frames), reference)
    finally:
        patch.undo()


# ---------------------------------------------------------------- the heavy frame
STEP_PEAK_LIMIT_MB = 400  # measured 100-181 MB (python -m simpletrack.bench.heavy 10000)


def test_a_ten_thousand_box_frame_steps_in_bounded_memory() -> None:
    scene = heavy_scene(10_000)
    tracker = tracker_module.Tracker(preset("nuscenes"))
    tracker.step(scene.first)
    tracemalloc.start()
    try:
        out = tracker.step(scene.second)
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert (out.update == 1).sum() > 1000  # it did match: not a trivially empty frame
    assert peak / 2**20 < STEP_PEAK_LIMIT_MB
