"""The compiled pair walks (core/pair_kernels.py) against the numpy paths they replace: the
association table equals ``distance_pairs`` over every same-class pair, and the compiled NMS
walk keeps exactly the boxes the gated all-pairs walk keeps, in the same order."""

from __future__ import annotations

import numpy as np
import numpy.typing as npt
import pytest

from simpletrack.core import nms as nms_module
from simpletrack.core import pair_kernels as pk
from simpletrack.core.boxes import Boxes
from simpletrack.core.config import Metric, TieOrder, VerticalOverlap
from simpletrack.core.geometry import distance_pairs

F64 = npt.NDArray[np.float64]
OVERLAP_METRICS = (Metric.GIOU_3D, Metric.IOU_3D, Metric.GIOU_BEV, Metric.IOU_BEV)


def crowded(n: int, classes: int, seed: int) -> tuple[F64, npt.NDArray[np.int32], F64]:
    """Boxes packed so that many overlap (NMS has work), scores rounded so that ties occur."""
    rng = np.random.default_rng(seed)
    p = np.empty((n, 7))
    p[:, 0:2] = rng.uniform(-6, 6, (n, 2))
    p[:, 2] = rng.uniform(-0.5, 0.5, n)
    p[:, 3] = rng.uniform(-np.pi, np.pi, n)
    p[:, 4:7] = rng.uniform(0.5, 4.5, (n, 3))
    dup = rng.random(n) < 0.2  # exact duplicates of an earlier box
    for i in np.flatnonzero(dup):
        p[i] = p[rng.integers(0, max(i, 1))]
    score = np.round(rng.random(n), 1)
    return p, rng.integers(0, classes, n).astype(np.int32), score


@pytest.mark.parametrize("exact", [True, False])
@pytest.mark.parametrize("seed", range(6))
def test_class_table_is_distance_pairs_over_same_class_pairs(seed: int, exact: bool) -> None:
    d, d_cls, _ = crowded(40, 4, seed)
    t, t_cls, _ = crowded(30, 4, seed + 100)
    kinds = np.array(
        [
            pk.overlap_kind(m in OVERLAP_METRICS[:2], m in (Metric.GIOU_3D, Metric.GIOU_BEV))
            for m in OVERLAP_METRICS
        ],
        dtype=np.int64,
    )
    table = pk.class_table(d, d_cls.astype(np.int64), t, t_cls.astype(np.int64), kinds, exact)
    vertical = VerticalOverlap.EXACT if exact else VerticalOverlap.REFERENCE
    same = d_cls[:, None] == t_cls[None, :]
    assert np.isinf(table[~same]).all()
    for code, metric in enumerate(OVERLAP_METRICS):
        ia, ib = np.nonzero(same & (d_cls[:, None] == code))
        want = distance_pairs(metric, d, t, ia, ib, vertical=vertical)
        assert ia.size > 0
        np.testing.assert_array_equal(table[ia, ib], want)  # bit for bit


def test_class_table_leaves_numpy_metrics_to_the_caller() -> None:
    d, d_cls, _ = crowded(10, 2, 1)
    kinds = np.array([pk.NOT_OVERLAP, pk.overlap_kind(True, True)], dtype=np.int64)
    table = pk.class_table(d, d_cls.astype(np.int64), d, d_cls.astype(np.int64), kinds, True)
    assert np.isinf(table[d_cls == 0]).all()
    assert np.isfinite(table[np.ix_(d_cls == 1, d_cls == 1)]).all()


@pytest.mark.parametrize("tie_order", list(TieOrder))
@pytest.mark.parametrize("vertical", list(VerticalOverlap))
@pytest.mark.parametrize("seed", range(8))
def test_compiled_nms_keeps_what_the_gated_walk_keeps(
    seed: int, vertical: VerticalOverlap, tie_order: TieOrder, monkeypatch: pytest.MonkeyPatch
) -> None:
    p, cls, score = crowded(150, 3, seed)
    boxes = Boxes(params=p, score=score, cls=cls)
    thr = np.array([0.01, 0.1, 0.5])
    compiled = nms_module.nms(boxes, thr, vertical=vertical, tie_order=tie_order)
    monkeypatch.setattr(nms_module, "_WALK_PAIRS", -1)  # force the large-frame path
    gated = nms_module.nms(boxes, thr, vertical=vertical, tie_order=tie_order)
    assert 0 < compiled.size < len(boxes)  # the frames are crowded enough to suppress
    np.testing.assert_array_equal(compiled, gated)


def test_stable_order_is_descending_score_class_by_class() -> None:
    # Two boxes far apart per class: nothing is suppressed, so the result is the walk order.
    p = np.zeros((6, 7))
    p[:, 0] = np.arange(6) * 100.0
    p[:, 4:7] = 1.0
    cls = np.array([1, 0, 1, 0, 1, 0], dtype=np.int32)
    score = np.array([0.5, 0.2, 0.9, 0.2, 0.5, 0.7])
    kept = nms_module.nms(Boxes(params=p, score=score, cls=cls), [0.5, 0.5])
    np.testing.assert_array_equal(kept, [5, 1, 3, 2, 0, 4])


def test_compiled_walks_equal_their_python_functions() -> None:
    p, cls, score = crowded(80, 2, 3)
    order = np.lexsort((-score, cls)).astype(np.int64)
    thr = np.array([0.1, 0.3])
    c64 = cls.astype(np.int64)
    kinds = np.array([pk.overlap_kind(True, True), pk.overlap_kind(False, False)], np.int64)
    with np.errstate(all="ignore"):  # the Python functions meet 0 * inf in clipping too
        plain_walk = pk.nms_walk.py(p, c64, order, thr, True)
        plain_table = pk.class_table.py(p, c64, p, c64, kinds, True)
    np.testing.assert_array_equal(pk.nms_walk(p, c64, order, thr, True), plain_walk)
    np.testing.assert_allclose(
        pk.class_table(p, c64, p, c64, kinds, True),
        plain_table,
        rtol=0,
        atol=1e-12,
    )
