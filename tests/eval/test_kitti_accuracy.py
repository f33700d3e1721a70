"""The ``kitti`` preset on the 10 KITTI train sequences. It is the WOD settings under KITTI's
class names, chosen by leave-one-sequence-out cross-validation (docs/KITTI_TUNING.md): it
tracks exactly as ``wod`` and gives the figures the docs quote for the train sequences (the
held-out figures come from ``simpletrack eval kitti --cv loso``)."""

from __future__ import annotations

from pathlib import Path

import pytest

from simpletrack.cli.eval import track_all
from simpletrack.core.config import preset
from simpletrack.datasets.kitti import KITTI_CLASSES, TRAIN_SEQUENCES
from simpletrack.eval.kitti import evaluate

KITTI = Path(__file__).resolve().parents[2].parent / "shared" / "data" / "kitti"

# sAMOTA, MOTA (%) and ID switches on the train sequences (README, docs/KITTI_TUNING.md).
TRAIN_FIGURES = {
    "Car": (87.63, 80.79, 2),
    "Pedestrian": (68.21, 62.41, 1),
    "Cyclist": (57.79, 49.32, 0),
}


def test_the_kitti_preset_is_the_wod_settings_under_kitti_class_names() -> None:
    kitti, wod = preset("kitti"), preset("wod")
    assert kitti.class_names == ("Car", "Pedestrian", "Cyclist")
    assert list(kitti.classes.values()) == list(wod.classes.values())
    assert kitti.model_dump(exclude={"classes"}) == wod.model_dump(exclude={"classes"})


@pytest.fixture(scope="module")
def figures(tmp_path_factory: pytest.TempPathFactory) -> dict[str, dict[str, float]]:
    needed = [KITTI / "labels", KITTI / "calib", KITTI / "detections" / "pointrcnn"]
    if not all(p.is_dir() for p in needed):
        pytest.skip(f"needs the KITTI train data in {KITTI}")
    out = tmp_path_factory.mktemp("kitti")
    results = track_all(KITTI, TRAIN_SEQUENCES, KITTI_CLASSES, preset("kitti"), out)
    return evaluate(results, KITTI / "labels", TRAIN_SEQUENCES, KITTI_CLASSES)


@pytest.mark.data
@pytest.mark.parametrize("cls", KITTI_CLASSES)
def test_the_kitti_preset_gives_the_documented_train_figures(
    cls: str, figures: dict[str, dict[str, float]]
) -> None:
    got = figures[cls]
    samota, mota, ids = TRAIN_FIGURES[cls]
    assert (round(got["sAMOTA"], 2), round(got["MOTA"], 2), int(got["IDS"])) == (
        samota,
        mota,
        ids,
    )
