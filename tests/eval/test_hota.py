"""HOTA (DetA, AssA, LocA) and IDF1 (IDP, IDR) of ``simpletrack eval kitti``: hand-computed
tiny cases through the label and result files, and the command on the real train sequences."""

from __future__ import annotations

import argparse
import json
import math
from pathlib import Path

import numpy as np
import pytest

import simpletrack.cli.eval as eval_cmd
from simpletrack.eval.hota import ALPHAS
from simpletrack.eval.kitti import evaluate
from simpletrack.eval.kitti_overlap import iou3d_pairs
from tests.eval.test_kitti import CAR, dontcare, label, result, score

KITTI = Path(__file__).resolve().parents[2].parent / "shared" / "data" / "kitti"
NEW = ("HOTA", "DetA", "AssA", "LocA", "IDF1", "IDP", "IDR")


def shift_for_iou(iou: float) -> float:
    """How far to slide a car along its length (x) for this 3D IoU with the original:
    (l - d) / (l + d) for two boxes of the same size and height."""
    length = CAR[2]
    return length * (1 - iou) / (1 + iou)


def test_perfect_tracking_scores_full_marks(tmp_path: Path) -> None:
    labels = [label(f, 7, "Car", 0.0) for f in range(5)] + [
        label(f, 8, "Car", 5.0) for f in range(5)
    ]
    results = [result(f, 1, 0.0) for f in range(5)] + [result(f, 2, 5.0) for f in range(5)]
    m = score(tmp_path, labels, results)
    for name in NEW:
        assert m[name] == pytest.approx(100.0), name


def test_a_track_split_between_two_ids_halves_association(tmp_path: Path) -> None:
    # One car over 4 frames, tracked as id 1 then id 2. Detection is perfect (DetA 1); each id
    # pair's association is 2 / (4 + 2 - 2) = 1/2 for each of its 2 matches, so AssA = 1/2 and
    # HOTA = sqrt(1/2). IDF1: the best id pairing keeps 2 of the 4 boxes on each side.
    labels = [label(f, 7, "Car", 0.0) for f in range(4)]
    results = [result(f, 1 if f < 2 else 2, 0.0) for f in range(4)]
    m = score(tmp_path, labels, results)
    assert m["DetA"] == pytest.approx(100.0)
    assert m["AssA"] == pytest.approx(50.0)
    assert m["HOTA"] == pytest.approx(100.0 * math.sqrt(0.5))
    assert m["IDF1"] == pytest.approx(50.0)  # 2 IDTP / (2 * 2 + 2 IDFP + 2 IDFN)
    assert m["IDP"] == pytest.approx(50.0)
    assert m["IDR"] == pytest.approx(50.0)


def test_a_false_track_costs_detection_not_association(tmp_path: Path) -> None:
    # 4 true positives and 4 boxes of a track where there is no car: DetA 4 / 8, AssA 1.
    labels = [label(f, 7, "Car", 0.0) for f in range(4)]
    results = [result(f, 1, 0.0) for f in range(4)] + [result(f, 2, 30.0) for f in range(4)]
    m = score(tmp_path, labels, results)
    assert m["DetA"] == pytest.approx(50.0)
    assert m["AssA"] == pytest.approx(100.0)
    assert m["LocA"] == pytest.approx(100.0)
    assert m["HOTA"] == pytest.approx(100.0 * math.sqrt(0.5))
    assert m["IDF1"] == pytest.approx(100.0 * 4 / (4 + 0.5 * 4))
    assert m["IDP"] == pytest.approx(50.0)
    assert m["IDR"] == pytest.approx(100.0)


def test_a_false_track_below_the_best_mota_threshold_is_not_scored(tmp_path: Path) -> None:
    # The same false track with a lower score: the best-MOTA threshold (1.0) removes it, and
    # HOTA/IDF1 are computed on the boxes that threshold keeps.
    labels = [label(f, 7, "Car", 0.0) for f in range(4)]
    results = [result(f, 1, 0.0) for f in range(4)] + [
        result(f, 2, 30.0, score=0.5) for f in range(4)
    ]
    m = score(tmp_path, labels, results)
    assert m["FP"] == 0
    assert m["HOTA"] == pytest.approx(100.0)
    assert m["IDF1"] == pytest.approx(100.0)


@pytest.mark.parametrize(("iou", "alphas_hit"), [(0.575, 11), (0.12, 2)])
def test_a_loose_box_matches_only_the_alphas_below_its_iou(
    tmp_path: Path, iou: float, alphas_hit: int
) -> None:
    # Every box of the track is off by the same IoU: it is a true positive at the alphas up to
    # that IoU (HOTA 1 there) and a miss plus a false positive above it (HOTA 0): HOTA is the
    # fraction of the 19 alphas it reaches. 0.12 is below the MOTA threshold 0.25 but still
    # matches at alpha 0.05 and 0.10.
    d = shift_for_iou(iou)
    labels = [label(f, 7, "Car", 0.0) for f in range(4)]
    results = [result(f, 1, d) for f in range(4)]
    m = score(tmp_path, labels, results)
    exact = iou3d_pairs(*(np.array([[*CAR, x, 1.5, 20.0, 0.0]]) for x in (0.0, d)))[0]
    assert exact == pytest.approx(iou)
    assert int((iou >= ALPHAS).sum()) == alphas_hit
    share = alphas_hit / len(ALPHAS)
    assert m["HOTA"] == pytest.approx(100.0 * share)
    assert m["DetA"] == pytest.approx(100.0 * share)
    assert m["AssA"] == pytest.approx(100.0 * share)
    # TrackEval's LocA at an alpha with no match is 1e-10 / 1e-10 = 1.
    assert m["LocA"] == pytest.approx(100.0 * (share * iou + (1 - share)))
    matched_by_mota = iou >= 0.25
    assert m["TP"] == (4 if matched_by_mota else 0)
    assert m["IDF1"] == pytest.approx(100.0 if matched_by_mota else 0.0)


def test_ignored_boxes_are_neither_misses_nor_false_positives(tmp_path: Path) -> None:
    # A tracked car, plus: a truncated car nobody tracks, a van tracked as a car, an occluded
    # frame the tracker misses, and a stray box inside a DontCare region. Each would cost
    # HOTA if it were counted.
    labels = [label(f, 7, "Car", 0.0, occ=3 if f == 2 else 0) for f in range(4)]
    labels += [label(f, 8, "Car", 10.0, trunc=1) for f in range(4)]
    labels += [label(f, 9, "Van", 20.0) for f in range(4)]
    labels += [dontcare(f, (90.0, 90.0, 210.0, 210.0)) for f in range(4)]
    results = [result(f, 1, 0.0) for f in range(4) if f != 2]
    results += [result(f, 2, 20.0) for f in range(4)]  # on the van
    results += [result(f, 3, 40.0) for f in range(4)]  # 2D box inside the DontCare region
    m = score(tmp_path, labels, results)
    assert (m["FP"], m["FN"]) == (0, 0)
    assert m["MOTA"] == pytest.approx(100.0)
    for name in NEW:
        assert m[name] == pytest.approx(100.0), name
    # Without the DontCare region, the stray track is 4 false positives next to 3 true ones.
    no_dc = [ln for ln in labels if "DontCare" not in ln]
    m = score(tmp_path, no_dc, results)
    assert m["FP"] == 4
    assert m["DetA"] == pytest.approx(100.0 * 3 / 7)


def test_sequences_add_up_with_their_own_ids(tmp_path: Path) -> None:
    # Sequence 0000 perfect, 0001 split half/half, the same ids in both (they are different
    # objects). Summed as TrackEval combines sequences: AssA (4 * 1 + 4 * 1/2) / 8 = 3/4,
    # IDTP 4 + 2 of 8: IDF1 3/4. (Averaging the two sequences' HOTA would give 85.36.)
    labels, res = tmp_path / "labels", tmp_path / "res"
    labels.mkdir()
    res.mkdir()
    gt = "\n".join(label(f, 7, "Car", 0.0) for f in range(4)) + "\n"
    for seq in ("0000", "0001"):
        (labels / f"{seq}.txt").write_text(gt)
    (res / "0000.txt").write_text("\n".join(result(f, 1, 0.0) for f in range(4)) + "\n")
    split = [result(f, 1 if f < 2 else 2, 0.0) for f in range(4)]
    (res / "0001.txt").write_text("\n".join(split) + "\n")
    m = evaluate(res, labels, ["0000", "0001"], ["Car"])["Car"]
    assert m["AssA"] == pytest.approx(75.0)
    assert m["HOTA"] == pytest.approx(100.0 * math.sqrt(0.75))
    assert m["IDF1"] == pytest.approx(75.0)


# ----------------------------------------------------------------------------- real data
@pytest.mark.data
def test_eval_kitti_prints_hota_and_idf1_for_every_class(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    needed = [KITTI / "labels", KITTI / "calib", KITTI / "detections" / "pointrcnn"]
    if not all(p.is_dir() for p in needed):
        pytest.skip(f"needs the KITTI train data in {KITTI}")
    parser = argparse.ArgumentParser(prog="simpletrack")
    eval_cmd.register(parser.add_subparsers(dest="command", required=True))
    js = tmp_path / "m.json"
    args = parser.parse_args(
        [
            *("eval", "kitti", "--data", str(KITTI), "--preset", "wod"),
            *("--results-dir", str(tmp_path / "out"), "--json", str(js)),
        ]
    )
    assert args.func(args) == 0
    out = capsys.readouterr().out
    for name in NEW:
        assert f"{name} %" in out
    figures = json.loads(js.read_text())
    assert set(figures) == {"Car", "Pedestrian", "Cyclist"}
    for cls, f in figures.items():
        shown = {k: f[k] for k in ("HOTA", "DetA", "AssA", "IDF1")}
        print(cls, shown)
        assert 0 < f["HOTA"] < 100, (cls, shown)
        # HOTA is the mean of sqrt(DetA * AssA) per alpha: never above the geometric mean of
        # the averaged DetA and AssA (Cauchy-Schwarz), and IDF1 lies between IDP and IDR.
        assert f["HOTA"] <= math.sqrt(f["DetA"] * f["AssA"]) + 1e-3, (cls, shown)
        assert min(f["IDP"], f["IDR"]) <= f["IDF1"] <= max(f["IDP"], f["IDR"]), (cls, shown)
