"""Pre-processing: class-aware 3D-IoU NMS and dropping degenerate boxes."""

from __future__ import annotations

import numpy as np
import numpy.typing as npt
import pytest

from simpletrack.core.boxes import Boxes
from simpletrack.core.config import TieOrder, VerticalOverlap
from simpletrack.core.geometry import iou_3d
from simpletrack.core.nms import drop_degenerate, nms
from simpletrack.core.ordering import descending_reference, descending_stable

F64 = npt.NDArray[np.float64]
I64 = npt.NDArray[np.int64]
CAR = [4.0, 2.0, 1.5]  # l, w, h


def boxes(rows: list[tuple[float, float, float, int]], size: list[float] = CAR) -> Boxes:
    """Rows of (x, y, score, class) for upright boxes of one size at z = 0, yaw = 0."""
    a = np.array(rows, dtype=np.float64).reshape(-1, 4)
    params = np.zeros((len(a), 7))
    params[:, 0:2] = a[:, 0:2]
    params[:, 4:7] = size
    return Boxes.from_arrays(params, a[:, 2], a[:, 3].astype(np.int32))


def reference_nms(
    b: Boxes, thr: F64, vertical: VerticalOverlap, tie_order: TieOrder = TieOrder.STABLE
) -> I64:
    """The reference's loop, per class: keep order[0], keep the rest with IoU <= threshold."""
    descending = descending_stable if tie_order is TieOrder.STABLE else descending_reference
    out: list[int] = []
    for code in np.unique(b.cls):
        rows = np.flatnonzero(b.cls == code)
        params = b.params[rows]
        order = descending(b.score[rows])
        while order.size > 0:
            first = order[0]
            out.append(int(rows[first]))
            iou = iou_3d(params[first : first + 1], params[order], vertical=vertical)[0]
            order = order[iou <= thr[code]]
    return np.array(out, dtype=np.int64)


def test_nms_keeps_the_lone_low_score_object_that_score_filtering_loses() -> None:
    # Fig. 2 of the paper. Row 1: a hard object seen once, with a low score. Row 2: an object
    # with a confident box and a shifted duplicate whose score is a little higher than row 1's.
    b = boxes(
        [
            (0.0, 8.0, 0.20, 0),  # 0: row 1, the only box of a real object
            (0.0, 0.0, 0.90, 0),  # 1: row 2, the good box
            (0.8, 0.3, 0.23, 0),  # 2: row 2, its duplicate
        ]
    )
    assert iou_3d(b.params[1:2], b.params[2:3])[0, 0] > 0.25
    # Any score threshold that removes the duplicate (> 0.23) also removes the lone object.
    for threshold in np.linspace(0.231, 1.0, 50):
        survivors = set(np.flatnonzero(b.score >= threshold).tolist())
        assert 0 not in survivors
    # NMS (nuScenes 0.1 and WOD 0.25) removes the duplicate and keeps the lone object.
    for thr in (0.1, 0.25):
        assert nms(b, np.array([thr])).tolist() == [1, 0]


def test_overlapping_boxes_of_different_classes_are_all_kept() -> None:
    b = boxes([(0.0, 0.0, 0.9, 1), (0.0, 0.0, 0.8, 0), (0.1, 0.0, 0.7, 1), (0.1, 0.0, 0.6, 0)])
    kept = nms(b, np.array([0.1, 0.1]))
    # One per class (the best of each), classes in ascending code.
    assert kept.tolist() == [1, 0]


def test_result_is_by_class_code_then_descending_score() -> None:
    b = boxes([(0, 0, 0.3, 2), (0, 20, 0.9, 0), (0, 40, 0.5, 2), (0, 60, 0.7, 0), (0, 80, 0.1, 1)])
    kept = nms(b, np.full(3, 0.25))
    assert kept.tolist() == [1, 3, 4, 2, 0]
    assert kept.dtype == np.int64


def test_suppression_is_strictly_above_the_threshold() -> None:
    # Same footprint shifted along x by 2.4 m: IoU = (4 - 2.4) / (4 + 2.4) = 0.25.
    b = boxes([(0.0, 0.0, 0.9, 0), (2.4, 0.0, 0.5, 0)])
    iou = iou_3d(b.params[:1], b.params[1:])[0, 0]
    assert iou == pytest.approx(0.25, abs=1e-12)
    assert nms(b, np.array([iou])).tolist() == [0, 1]  # IoU <= threshold: kept
    assert nms(b, np.array([iou - 1e-9])).tolist() == [0]


def test_equal_scores_keep_input_order_by_default() -> None:
    # Three equal-score duplicates: the first in input order wins, on every machine.
    b = boxes([(0.0, 0.0, 0.5, 0), (0.2, 0.0, 0.5, 0), (0.4, 0.0, 0.5, 0)])
    assert nms(b, np.array([0.25])).tolist() == [0]


def test_reference_tie_order_is_numpys_classic_introsort() -> None:
    # Measured on the reference's nuScenes output (scene-0003, bicycles of frame 0): 19 sorted
    # scores whose tied 0.10s come out as rows 17, 16, 18, whatever NumPy this machine has.
    s = [0.23, 0.2, 0.17, 0.16, 0.15, 0.15, 0.13, 0.13, 0.12, 0.12, 0.12]
    s += [0.11] * 5 + [0.1] * 3
    order = descending_reference(np.array(s))
    assert order.tolist()[11:] == [11, 12, 13, 14, 15, 17, 16, 18]
    for n in (0, 1, 5, 17, 18, 40, 300):
        a = np.round(np.random.default_rng(n).uniform(0, 1, n), 2)
        assert np.all(np.diff(a[order_of(a)]) <= 0)
    b = boxes([(0.0, 0.0, 0.5, 0), (0.2, 0.0, 0.5, 0), (0.4, 0.0, 0.5, 0)])
    assert nms(b, np.array([0.25]), tie_order=TieOrder.REFERENCE).tolist() == [2]


def order_of(a: F64) -> I64:
    return descending_reference(a)


def test_vertical_overlap_mode_is_honoured() -> None:
    # Same footprint; the low-score box's height range sits inside the other's.
    params = np.array([[0, 0, 0, 0, 4, 2, 4.0], [0, 0, 0.2, 0, 4, 2, 1.0]])
    b = Boxes.from_arrays(params, [0.9, 0.5], [0, 0])
    assert iou_3d(params[:1], params[1:])[0, 0] == pytest.approx(0.25)
    assert nms(b, np.array([0.5])).tolist() == [0, 1]
    # The reference's vertical formula sees IoU ~0.85 here: the contained box is suppressed.
    assert nms(b, np.array([0.5]), vertical=VerticalOverlap.REFERENCE).tolist() == [0]


def test_empty_and_single_box() -> None:
    empty = nms(Boxes.empty(), np.array([0.1]))
    assert empty.dtype == np.int64 and empty.size == 0
    assert nms(boxes([(3.0, 4.0, 0.1, 0)]), np.array([0.1])).tolist() == [0]


def test_missing_class_threshold_is_an_error() -> None:
    with pytest.raises(ValueError, match="thresholds"):
        nms(boxes([(0, 0, 0.5, 0), (9, 9, 0.5, 3)]), np.array([0.1, 0.1]))


@pytest.mark.parametrize("vertical", list(VerticalOverlap))
def test_a_thousand_boxes_match_the_reference_loop(vertical: VerticalOverlap) -> None:
    rng = np.random.default_rng(7)
    # 400 objects, each detected 1-4 times with jitter; some objects overlap each other.
    objects = np.zeros((400, 7))
    objects[:, 0:2] = rng.uniform(-60, 60, (400, 2))
    objects[:, 2] = rng.uniform(-0.5, 0.5, 400)
    objects[:, 3] = rng.uniform(-np.pi, np.pi, 400)
    objects[:, 4:7] = rng.uniform([3.5, 1.6, 1.4], [5.0, 2.1, 1.9], (400, 3))
    source = rng.integers(0, 400, 1000)
    params = objects[source] + rng.normal(0, 1, (1000, 7)) * [0.4, 0.4, 0.1, 0.1, 0.2, 0.1, 0.1]
    params[:, 4:7] = np.abs(params[:, 4:7])
    score = np.round(rng.uniform(0, 1, 1000), 2)  # many ties
    cls = rng.integers(0, 3, 1000).astype(np.int32)
    b = Boxes.from_arrays(params, score, cls)
    thr = np.array([0.1, 0.25, 0.5])
    kept = nms(b, thr, vertical=vertical)
    np.testing.assert_array_equal(kept, reference_nms(b, thr, vertical))
    ref_kept = nms(b, thr, vertical=vertical, tie_order=TieOrder.REFERENCE)
    np.testing.assert_array_equal(ref_kept, reference_nms(b, thr, vertical, TieOrder.REFERENCE))
    assert 300 < kept.size < 1000  # duplicates were removed, distinct objects kept
    iou = iou_3d(params[kept], params[kept], vertical=vertical)
    same = cls[kept][:, None] == cls[kept][None, :]
    np.fill_diagonal(same, False)
    assert np.all(iou[same] <= thr[cls[kept]][:, None].repeat(kept.size, 1)[same])


def test_drop_degenerate_keeps_only_finite_boxes_with_positive_sizes() -> None:
    params = np.tile([0.0, 0.0, 0.0, 0.0, 4.0, 2.0, 1.5], (7, 1))
    params[1, 4] = 0.0  # zero length
    params[2, 5] = -1.0  # negative width
    params[3, 6] = 0.0  # zero height
    params[4, 0] = np.nan
    params[5, 3] = np.inf
    score = np.array([0.5, 0.5, 0.5, 0.5, 0.5, 0.5, np.nan])
    b = Boxes.from_arrays(params, score, np.zeros(7))
    assert drop_degenerate(b).tolist() == [0]
    with_velocity = Boxes.from_arrays(
        params[:1].repeat(2, 0), [0.5, 0.5], [0, 0], [[1, 0], [np.nan, 0]]
    )
    assert drop_degenerate(with_velocity).tolist() == [0]
    assert drop_degenerate(Boxes.empty()).dtype == np.int64
