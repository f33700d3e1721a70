"""The KITTI 3D MOT evaluator: the reference figures on real data, and its rules on tiny cases."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from shapely.geometry import Polygon

from simpletrack.datasets.kitti import TRAIN_SEQUENCES
from simpletrack.eval.kitti import NO_THRESHOLD, ClassEvaluation, evaluate, recall_points
from simpletrack.eval.kitti_data import build_problem
from simpletrack.eval.kitti_overlap import bev_corners, convex_quad_intersection_area, iou3d_pairs

DATA = Path(__file__).resolve().parents[2].parent / "shared" / "data"
REFERENCE = DATA / "reference" / "kitti_train"


# ----------------------------------------------------------------------------- real data
@pytest.mark.data
@pytest.mark.parametrize("tracker", ["simpletrack", "ab3dmot"])
def test_reproduces_the_reference_metrics(tracker: str) -> None:
    results = REFERENCE / tracker / "data_0"
    if not results.is_dir() or not (DATA / "kitti" / "labels").is_dir():
        pytest.skip(f"needs {results} and {DATA / 'kitti' / 'labels'}")
    expected = json.loads((REFERENCE / tracker / "metrics.json").read_text())
    got = evaluate(results, DATA / "kitti" / "labels", TRAIN_SEQUENCES, list(expected))
    for cls, figures in expected.items():
        for name, value in figures.items():
            assert got[cls][name] == pytest.approx(value, abs=0.05), (cls, name)


# ----------------------------------------------------------------------------- tiny cases
CAR = (1.5, 1.6, 3.9)  # h, w, l
TALL = (100.0, 100.0, 200.0, 200.0)  # a 2D box 100 px high


def _box(x: float, z: float = 20.0, size: tuple[float, float, float] = CAR) -> str:
    h, w, length = size
    return f"{h} {w} {length} {x} 1.5 {z} 0.0"


def label(frame: int, tid: int, kind: str, x: float, trunc: int = 0, occ: int = 0) -> str:
    x1, y1, x2, y2 = TALL
    return f"{frame} {tid} {kind} {trunc} {occ} 0 {x1} {y1} {x2} {y2} {_box(x)}"


def dontcare(frame: int, box2d: tuple[float, float, float, float]) -> str:
    return (
        f"{frame} -1 DontCare -1 -1 -10 {' '.join(map(str, box2d))} -1 -1 -1 -1000 -1000 -1000 -10"
    )


def result(
    frame: int,
    tid: int,
    x: float,
    score: float = 1.0,
    kind: str = "Car",
    box2d: tuple[float, float, float, float] = TALL,
) -> str:
    return f"{frame} {tid} {kind} 0 0 0 {' '.join(map(str, box2d))} {_box(x)} {score}"


def score(
    tmp_path: Path, labels: list[str], results: list[str], cls: str = "Car"
) -> dict[str, float]:
    (tmp_path / "labels").mkdir(exist_ok=True)
    (tmp_path / "res").mkdir(exist_ok=True)
    (tmp_path / "labels" / "0000.txt").write_text("\n".join(labels) + "\n")
    (tmp_path / "res" / "0000.txt").write_text("\n".join(results) + "\n")
    return evaluate(tmp_path / "res", tmp_path / "labels", ["0000"], [cls])[cls]


def test_perfect_tracking_scores_full_marks(tmp_path: Path) -> None:
    labels = [label(f, 7, "Car", 0.0) for f in range(5)]
    labels += [label(f, 8, "Car", 5.0) for f in range(5)]
    results = [result(f, 1, 0.0) for f in range(5)] + [result(f, 2, 5.0) for f in range(5)]
    m = score(tmp_path, labels, results)
    assert (m["TP"], m["FP"], m["FN"], m["IDS"], m["FRAG"]) == (10, 0, 0, 0, 0)
    assert m["MOTA"] == pytest.approx(100) and m["MOTP"] == pytest.approx(100)
    assert m["MT"] == 100 and m["ML"] == 0


def test_identity_switch_is_counted(tmp_path: Path) -> None:
    labels = [label(f, 7, "Car", 0.0) for f in range(4)]
    results = [result(f, 1 if f < 2 else 2, 0.0) for f in range(4)]
    m = score(tmp_path, labels, results)
    assert m["IDS"] == 1
    assert m["MOTA"] == pytest.approx(75.0)


def test_no_switch_across_an_ignored_frame(tmp_path: Path) -> None:
    # Frame 2 of the car is truncated (ignored): the id change across it is not a switch.
    labels = [label(f, 7, "Car", 0.0, trunc=1 if f == 2 else 0) for f in range(4)]
    results = [result(f, 1 if f < 2 else 2, 0.0) for f in range(4)]
    m = score(tmp_path, labels, results)
    assert m["IDS"] == 0 and m["FN"] == 0 and m["TP"] == 4


def test_fragment_is_counted(tmp_path: Path) -> None:
    labels = [label(f, 7, "Car", 0.0) for f in range(5)]
    results = [result(f, 1, 0.0) for f in (0, 1, 3, 4)]
    m = score(tmp_path, labels, results)
    assert (m["FRAG"], m["IDS"], m["FN"]) == (1, 0, 1)


def test_dontcare_region_hides_an_unmatched_box(tmp_path: Path) -> None:
    labels = [label(0, 7, "Car", 0.0), dontcare(0, (90.0, 90.0, 210.0, 210.0))]
    stray = result(0, 2, 30.0)  # no car there; its 2D box lies inside the DontCare region
    assert score(tmp_path, labels, [result(0, 1, 0.0), stray])["FP"] == 0
    elsewhere = result(0, 2, 30.0, box2d=(500.0, 100.0, 600.0, 200.0))
    assert score(tmp_path, labels, [result(0, 1, 0.0), elsewhere])["FP"] == 1


def test_small_unmatched_boxes_are_not_false_positives(tmp_path: Path) -> None:
    labels = [label(0, 7, "Car", 0.0)]
    small = result(0, 2, 30.0, box2d=(500.0, 100.0, 600.0, 125.0))
    assert score(tmp_path, labels, [result(0, 1, 0.0), small])["FP"] == 0


def test_van_is_neither_missed_nor_a_false_positive_for_car(tmp_path: Path) -> None:
    labels = [label(0, 7, "Car", 0.0), label(0, 8, "Van", 10.0), label(0, 9, "Van", 20.0)]
    results = [result(0, 1, 0.0), result(0, 2, 10.0)]  # the second car box sits on a van
    m = score(tmp_path, labels, results)
    assert (m["FP"], m["FN"], m["TP"]) == (0, 0, 2)  # the matched van still counts in TP
    assert m["MOTA"] == 100


def test_other_classes_are_not_loaded(tmp_path: Path) -> None:
    labels = [label(0, 7, "Car", 0.0), label(0, 8, "Pedestrian", 10.0)]
    results = [result(0, 1, 0.0), result(0, 2, 10.0, kind="Pedestrian")]
    car = score(tmp_path, labels, results)
    assert (car["TP"], car["FP"], car["FN"]) == (1, 0, 0)


def test_a_whole_track_goes_when_its_mean_score_is_below_the_threshold(tmp_path: Path) -> None:
    labels = [label(f, 7, "Car", 0.0) for f in range(3)]
    results = [result(f, 1, 0.0, score=s) for f, s in zip(range(3), (9.0, -5.0, -7.0), strict=True)]
    score(tmp_path, labels, results)
    problem = build_problem(tmp_path / "labels", tmp_path / "res", ["0000"], "Car")
    assert ClassEvaluation(problem).run(NO_THRESHOLD).tp == 3
    removed = ClassEvaluation(problem).run(0.0)  # mean -1: even the 9.0 box goes
    assert (removed.tp, removed.fn) == (0, 3)


def test_means_are_re_averaged_from_run_to_run(tmp_path: Path) -> None:
    # Summed box by box, these ten scores' mean 2.71485 re-averages to 2.7148499999999998:
    # with the first mean as the threshold, the second run drops the track (AB3DMOT's quirk).
    raw = [4.8191, 6.4647, -1.8737, -2.6598, 7.0292, 2.1932, 6.1474, -2.9747, 2.3446, 5.6585]
    labels = [label(f, 7, "Car", 0.0) for f in range(10)]
    results = [result(f, 1, 0.0, score=s) for f, s in enumerate(raw)]
    score(tmp_path, labels, results)
    problem = build_problem(tmp_path / "labels", tmp_path / "res", ["0000"], "Car")
    chained = ClassEvaluation(problem)
    first = chained.run(NO_THRESHOLD)
    mean = float(first.tp_scores[0])
    assert ClassEvaluation(problem).run(mean).tp == 10  # a fresh evaluator keeps it
    assert chained.run(mean).tp == 0


def test_recall_points_step_by_a_fortieth() -> None:
    points = recall_points(np.arange(100, 0, -1, dtype=np.float64), num_gt=100)
    assert len(points) == 40
    assert points[0][1] == pytest.approx(1 / 40)
    assert points[-1][1] == pytest.approx(1.0)
    thresholds = [t for t, _ in points]
    assert thresholds == sorted(thresholds, reverse=True)


def test_duplicate_track_id_in_a_frame_is_an_error(tmp_path: Path) -> None:
    with pytest.raises(ValueError, match="appears twice"):
        score(tmp_path, [label(0, 7, "Car", 0.0)], [result(0, 1, 0.0), result(0, 1, 3.0)])


# ----------------------------------------------------------------------------- IoU3D
def test_iou3d_matches_polygon_clipping() -> None:
    rng = np.random.default_rng(3)
    n = 400
    a = np.column_stack(
        [
            rng.uniform(0.5, 3, n), rng.uniform(0.5, 3, n), rng.uniform(0.5, 6, n),
            rng.uniform(-2, 2, n), rng.uniform(-1, 1, n), rng.uniform(-2, 2, n),
            rng.uniform(-np.pi, np.pi, n),
        ]
    )  # fmt: skip
    b = a[rng.permutation(n)]
    b[:50] = a[:50]  # identical boxes
    ca, cb = bev_corners(a), bev_corners(b)
    area = np.array([Polygon(p).intersection(Polygon(q)).area for p, q in zip(ca, cb, strict=True)])
    assert np.allclose(convex_quad_intersection_area(ca, cb), area, atol=1e-9)
    overlap = np.clip(
        np.minimum(a[:, 4], b[:, 4]) - np.maximum(a[:, 4] - a[:, 0], b[:, 4] - b[:, 0]), 0, None
    )
    inter = area * overlap
    union = a[:, :3].prod(axis=1) + b[:, :3].prod(axis=1) - inter
    assert np.allclose(iou3d_pairs(a, b), inter / union, atol=1e-9)
    assert np.allclose(iou3d_pairs(a[:50], b[:50]), 1.0)


def test_iou3d_uses_the_true_vertical_overlap() -> None:
    a = np.array([[2.0, 2.0, 4.0, 0.0, 0.0, 10.0, 0.3]])
    b = a.copy()
    b[0, 4] = -1.0  # lifted by half its height: half the volume shared
    assert iou3d_pairs(a, b)[0] == pytest.approx(1 / 3)
    b[0, 4] = -2.5  # entirely above
    assert iou3d_pairs(a, b)[0] == 0.0
