"""``python -m simpletrack.bench.gaps``: what an outage does to track ids. A synthetic street
gives exact answers (constant velocity kept, a jump changed, an exit gone); the KITTI run only
checks the accounting, since which gap keeps more on real data is not fixed by construction."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from simpletrack.bench.gaps import ClassTruth, evaluator_matches, main, sequence_survival
from simpletrack.core.boxes import Boxes
from simpletrack.core.config import preset
from simpletrack.datasets.kitti import FRAME_PERIOD, SequenceFrame, camera_to_tracker
from simpletrack.eval.kitti_data import TrackingRows

KITTI = Path(__file__).resolve().parents[2].parent / "shared" / "data" / "kitti"
N_FRAMES = 160  # one cut, at frame 100 (10 s)
CAR = (1.5, 1.6, 4.0)  # h, w, l


def _car(x: float, z: float) -> list[float]:
    return [*CAR, x, 1.5, z, 0.0]


def _street() -> tuple[list[SequenceFrame], TrackingRows]:
    """Three cars: 1 drives away at 2 m/s; 2 stands still, then jumps 20 m at frame 105;
    3 stands still and is last seen in frame 104."""
    frame, obj, cam = [], [], []
    for k in range(N_FRAMES):
        t = k * FRAME_PERIOD
        frame += [k, k]
        obj += [1, 2]
        cam += [_car(2.0, 10.0 + 2.0 * t), _car(-6.0, 15.0 if k < 105 else 35.0)]
        if k <= 104:
            frame.append(k)
            obj.append(3)
            cam.append(_car(8.0, 25.0))
    f, o, c = np.array(frame), np.array(obj), np.array(cam)
    frames = []
    for k in range(N_FRAMES):
        sel = f == k
        boxes = Boxes.from_arrays(
            camera_to_tracker(c[sel]), np.full(sel.sum(), 0.9), np.zeros(sel.sum())
        )
        frames.append(SequenceFrame(index=k, boxes=boxes, stamp=k * FRAME_PERIOD))
    n = len(f)
    labels = TrackingRows(
        frame=f,
        track_id=o,
        kind=np.full(n, "car"),
        truncation=np.zeros(n),
        occlusion=np.zeros(n),
        box2d=np.zeros((n, 4)),
        cam=c,
        score=np.zeros(n),
    )
    return frames, labels


def test_constant_velocity_keeps_its_id_a_jump_changes_it_an_exit_is_gone() -> None:
    config = preset("kitti")
    frames, labels = _street()
    truth = {"Car": ClassTruth.load(labels, "Car", 0, N_FRAMES)}
    result = sequence_survival(frames, truth, config, [0.0, 1.0])
    none, one = result[0.0]["Car"], result[1.0]["Car"]
    assert (none.cuts, none.alive, none.kept, none.changed, none.gone) == (1, 3, 3, 0, 0)
    assert (one.cuts, one.alive, one.kept, one.changed, one.gone) == (1, 3, 1, 1, 1)
    assert one.gone_labelled == 0
    assert one.share_kept == 0.5
    # The moving car is where its velocity says, the jumped one 20 m off (the exit unlabelled).
    assert sorted(one.pred_err) == pytest.approx([0.0, 20.0], abs=0.2)


def test_a_gap_longer_than_the_rest_of_the_sequence_has_no_cut() -> None:
    frames, labels = _street()
    truth = {"Car": ClassTruth.load(labels, "Car", 0, N_FRAMES)}
    result = sequence_survival(frames, truth, preset("kitti"), [6.0])
    assert result[6.0]["Car"].cuts == 0


def test_the_evaluator_rule_matches_the_most_pairs_over_iou_a_quarter() -> None:
    # Boxes 4 m long along x: track 0 overlaps truth 1 best (IoU 0.6) and truth 0 less (0.33),
    # track 1 only truth 1 (0.6); the assignment takes both matches over the one best pair.
    gt = np.array([_car(0.0, 10.0), _car(3.0, 10.0), _car(20.0, 10.0)])
    trk = np.array([_car(2.0, 10.0), _car(4.0, 10.0)])
    gi, ti = evaluator_matches(gt, trk)
    assert sorted(zip(gi.tolist(), ti.tolist(), strict=True)) == [(0, 0), (1, 1)]
    assert evaluator_matches(gt[2:], trk)[0].size == 0


@pytest.mark.data
@pytest.mark.skipif(not (KITTI / "labels" / "0000.txt").is_file(), reason="needs KITTI data")
def test_kitti_counts_add_up(tmp_path: Path) -> None:
    out = tmp_path / "gaps.json"
    assert main(["--data", str(KITTI), "--seqs", "0000", "--gaps", "0,1", "--json", str(out)]) == 0
    gaps = {g["gap_s"]: g for g in json.loads(out.read_text())["gaps"]}
    assert set(gaps) == {0.0, 1.0}
    for g in gaps.values():
        for s in [g, *g["classes"].values()]:
            assert s["kept"] + s["changed"] + s["gone"] == s["alive"]
            assert 0 <= s["gone_labelled"] <= s["gone"]
    # The same cuts see the same objects alive: nothing before a cut depends on the gap.
    assert gaps[0.0]["cuts"] == gaps[1.0]["cuts"] >= 1
    assert gaps[0.0]["alive"] == gaps[1.0]["alive"] > 0
