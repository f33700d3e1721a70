"""The plausibility checks as pure functions: each unit or convention mistake is named with
its likely cause, a clean frame is not, and no real KITTI or nuScenes frame trips any."""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from simpletrack.core.boxes import Boxes
from simpletrack.core.config import TrackerConfig, preset
from simpletrack.server.plausibility import Cause, Finding, StartThresholds, check_frame
from simpletrack.wire import BoxArrays
from simpletrack.wire.codec import Rejection, decode_detection_frame, encode_detection_frame
from simpletrack.wire.convert import boxes_to_wire

DATA = Path(__file__).resolve().parents[2].parent / "shared" / "data"
NOW = 1_760_000_000 * 10**9  # the service's clock at receipt
KITTI = preset("kitti")
THRESHOLDS = StartThresholds.of(KITTI)


def street(n: int = 20, score: float = 0.9) -> BoxArrays:
    """n cars on a 100 m stretch, headings over the full circle: a frame real data could be."""
    rng = np.random.default_rng(0)
    return BoxArrays(
        classes=("Car",),
        class_index=np.zeros(n, np.int32),
        center=np.column_stack(
            [rng.uniform(-50, 50, n), rng.uniform(-20, 20, n), np.full(n, -1.0)]
        ).astype(np.float32),
        size=np.tile(np.array([4.5, 1.8, 1.6], np.float32), (n, 1)),
        yaw=rng.uniform(-np.pi, np.pi, n).astype(np.float32),
        score=np.full(n, score),
    )


def check(
    boxes: BoxArrays,
    stamp_ns: int = NOW - 30_000_000,
    has_pose: bool = False,
    key_frame: bool = True,
    least_lag_ns: int | None = None,
) -> list[Finding]:
    codes = np.zeros(len(boxes), np.int32)
    found = check_frame(
        boxes,
        stamp_ns,
        NOW,
        has_pose=has_pose,
        codes=codes,
        thresholds=THRESHOLDS,
        key_frame=key_frame,
        least_lag_ns=least_lag_ns,
    )
    # The worker passes the decoder's extents of the columns instead: the same findings.
    payload = encode_detection_frame(
        vehicle="v", sensor="s", seq=1, stamp_ns=stamp_ns, frame_id="base_link", boxes=boxes
    )
    decoded = decode_detection_frame(payload, class_codes={"Car": 0})
    if not isinstance(decoded, Rejection):  # past the decoder's bounds: never checked
        assert decoded.codes is not None
        again = check_frame(
            decoded.boxes,
            stamp_ns,
            NOW,
            has_pose=has_pose,
            codes=decoded.codes,
            thresholds=THRESHOLDS,
            key_frame=key_frame,
            least_lag_ns=least_lag_ns,
            extents=decoded.extents,
        )
        assert again == found
    return found


def causes(found: list[Finding]) -> list[Cause]:
    return [f.cause for f in found]


def test_a_clean_frame_and_an_empty_one_find_nothing() -> None:
    assert check(street()) == []
    assert check(street(0)) == []


def test_sizes_in_decimetres() -> None:
    (f,) = check(replace(street(), size=street().size * 10))
    assert f.cause is Cause.SIZE_UNIT
    assert "median longest side 45.0" in f.hint
    # One long box among cars is a trailer, not a unit.
    size = street().size.copy()
    size[0] = [26.6, 2.5, 4.0]
    assert check(replace(street(), size=size)) == []


def test_centres_in_millimetres() -> None:
    (f,) = check(replace(street(), center=street().center * 1000))
    assert f.cause is Cause.CENTER_UNIT
    assert "millimetres" in f.hint and f.value > 50_000
    # A lone box 40 km out in the sensor's own frame (the frame has a pose) is just as wrong.
    one = replace(street(1), center=np.array([[40_000.0, 5.0, -1.0]], np.float32))
    assert check(one) == []  # without a pose the frame may be a map's: no verdict
    assert causes(check(one, has_pose=True)) == [Cause.CENTER_UNIT]


def test_yaw_in_degrees() -> None:
    (f,) = check(replace(street(), yaw=np.degrees(street().yaw)))
    assert f.cause is Cause.YAW_DEGREES
    assert f"max |yaw| {f.value:.1f}" in f.hint and "degrees" in f.hint
    # A [0, 2π) heading shifted by a quarter turn is still radians.
    assert check(replace(street(), yaw=street().yaw + np.float32(np.pi * 1.5))) == []


def test_logit_scores_name_the_minimum() -> None:
    found = check(replace(street(), score=np.linspace(-3.0, 2.0, 20)))
    assert causes(found)[0] is Cause.SCORE_RANGE
    assert "scores look like logits (min -3)" in found[0].hint
    assert "[0, 1]" in found[0].hint
    (f,) = check(replace(street(), score=np.full(20, 87.0)))
    assert f.cause is Cause.SCORE_RANGE and "logits or percentages (max 87)" in f.hint


def test_every_score_under_the_start_threshold() -> None:
    (f,) = check(street(score=0.3))
    assert f.cause is Cause.SCORE_UNDER_THRESHOLD
    assert "lowest threshold 0.7" in f.hint and "no track can start" in f.hint
    # Non-key frames start tracks at the tracker's non-key threshold (0.5): 0.6 can.
    assert check(street(score=0.6), key_frame=False) == []
    assert causes(check(street(score=0.4), key_frame=False)) == [Cause.SCORE_UNDER_THRESHOLD]
    # A few weak boxes are an ordinary frame (KITTI has frames of up to 6 such boxes).
    assert check(street(6, score=0.3)) == []
    # Boxes of ignored classes (code -1) do not count.
    weak = street(score=0.3)
    ignored = np.full(len(weak), -1, np.int32)
    assert check_frame(weak, NOW, NOW, codes=ignored, thresholds=THRESHOLDS) == []
    # ... nor does a strong one: 20 weak tracked boxes and a sure box of an ignored class.
    mixed = replace(street(21, score=0.3), score=np.r_[np.full(20, 0.3), 0.99])
    codes = np.r_[np.zeros(20, np.int32), np.int32(-1)].astype(np.int32)
    for key_frame in (True, False):
        (f,) = check_frame(mixed, NOW, NOW, codes=codes, thresholds=THRESHOLDS, key_frame=key_frame)
        assert f.cause is Cause.SCORE_UNDER_THRESHOLD and "max score 0.3 of 20 boxes" in f.hint


@pytest.mark.parametrize(
    ("stamp_ns", "cause", "words"),
    [
        (NOW // 10**9, Cause.STAMP_SECONDS, "stamp looks like seconds"),
        (NOW // 10**6 - 2500, Cause.STAMP_MILLISECONDS, "stamp looks like milliseconds"),
        (NOW // 10**3, Cause.STAMP_MICROSECONDS, "stamp looks like microseconds"),
        (NOW - 3600 * 10**9, Cause.STAMP_OFFSET, "clock is 3600 s behind"),
        (NOW + 120 * 10**9, Cause.STAMP_OFFSET, "clock is 120 s ahead of"),
        (5 * 10**9, Cause.STAMP_OFFSET, "or this is a replay"),
    ],
)
def test_stamps_far_from_the_receipt(stamp_ns: int, cause: Cause, words: str) -> None:
    (f,) = check(street(), stamp_ns=stamp_ns)
    assert f.cause is cause and words in f.hint, f.hint


def test_a_late_frame_of_a_sensor_whose_frames_come_in_time_is_fine() -> None:
    # 20 s late (recovered after an outage, say) while its sensor's least delay lately is
    # 30 ms: a delivery's lateness, not a clock's.
    assert check(street(), stamp_ns=NOW - 20 * 10**9, least_lag_ns=30_000_000) == []
    # The same frame from a sensor whose every frame lately came as late: its clock.
    (f,) = check(street(), stamp_ns=NOW - 20 * 10**9, least_lag_ns=20 * 10**9)
    assert f.cause is Cause.STAMP_OFFSET and "clock is 20.0 s behind" in f.hint


def test_every_mistake_of_one_frame_is_reported() -> None:
    s = street()
    bad = replace(s, yaw=np.degrees(s.yaw), score=s.score - 3.0)
    assert set(causes(check(bad, stamp_ns=NOW // 10**9))) == {
        Cause.YAW_DEGREES,
        Cause.SCORE_RANGE,
        Cause.SCORE_UNDER_THRESHOLD,
        Cause.STAMP_SECONDS,
    }


# ------------------------------------------------------------------ real data
def _real_frames() -> Iterator[tuple[str, TrackerConfig, Boxes]]:
    from simpletrack.datasets import kitti, nuscenes

    kitti_dir, nus_dir = DATA / "kitti", DATA / "nuscenes" / "centerpoint_val"
    if not (kitti_dir / "detections").is_dir() or not nus_dir.is_dir():
        pytest.skip(f"needs {kitti_dir / 'detections'} and {nus_dir}")
    seqs = sorted(p.stem for p in (kitti_dir / "detections" / "pointrcnn" / "Car").glob("*.txt"))
    classes = ["Car", "Pedestrian", "Cyclist"]
    for seq in seqs:
        for f in kitti.load_sequence(kitti_dir, seq, KITTI, classes):
            yield f"kitti {seq} frame {f.index}", KITTI, f.boxes
    nus = preset("nuscenes")
    for path in nuscenes.scene_files(nus_dir):
        for g in nuscenes.read_scene(path, list(nus.class_names)):
            yield f"nuscenes {path.stem} frame {g.index}", nus, g.boxes


def test_no_real_frame_trips_any_check() -> None:
    """KITTI PointRCNN (scores as the tracker gets them, probabilities) under the kitti
    preset, nuScenes CenterPoint under the nuscenes preset; 50 ms in transit."""
    tripped, n = [], 0
    for where, config, boxes in _real_frames():
        wire = boxes_to_wire(boxes, config.class_names)
        found = check_frame(
            wire,
            NOW - 50_000_000,
            NOW,
            codes=wire.class_index,
            thresholds=StartThresholds.of(config),
        )
        n += 1
        if found:
            tripped.append(f"{where}: {[f.hint for f in found]}")
    assert n > 10_000
    assert tripped == [], tripped[:5]
