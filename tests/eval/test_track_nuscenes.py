"""``simpletrack track nuscenes`` runs one tracker for all classes: its rows are the
per-class trackers' rows (the reference's way), box for box and id for id."""

from __future__ import annotations

from pathlib import Path

import pytest

from simpletrack.core.config import TieOrder, VerticalOverlap, preset
from simpletrack.eval.track_nuscenes import track_scene

DATA = Path(__file__).resolve().parents[3] / "shared" / "data"
DETS = DATA / "nuscenes" / "centerpoint_val"
SCENES = ("scene-0003", "scene-0012", "scene-0103", "scene-0553")

pytestmark = [
    pytest.mark.data,
    pytest.mark.skipif(not DETS.is_dir(), reason="needs ../shared/data/nuscenes"),
]


@pytest.mark.parametrize("ties", list(TieOrder))
@pytest.mark.parametrize("scene", SCENES)
def test_one_tracker_for_all_classes_writes_the_per_class_rows(scene: str, ties: TieOrder) -> None:
    config = preset("nuscenes").with_overrides(
        vertical_overlap=VerticalOverlap.REFERENCE, tie_order=ties
    )
    one = list(track_scene(DETS / f"{scene}.txt", config))
    per_class = list(track_scene(DETS / f"{scene}.txt", config, per_class=True))
    assert len(one) > 500 and len({r["cls"] for r in one}) >= 3
    assert one == per_class
