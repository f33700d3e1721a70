"""The simulated fleet: reproducible, its ground truth consistent, its detector faulty in the
ways it claims, and trackable by the core tracker to a stated MOTA."""

from __future__ import annotations

import math

import numpy as np
import pytest
from pydantic import ValidationError

from simpletrack.core.boxes import Boxes
from simpletrack.core.config import preset
from simpletrack.core.geometry import iou_3d
from simpletrack.eval.clear_mot import MotCounts, MotScorer
from simpletrack.sim.simulator import (
    DetectorModel,
    FleetSimulator,
    SensorFrame,
    SimConfig,
    occlusion,
)

FRAMES = 60


def run(config: SimConfig, n: int = FRAMES) -> list[list[SensorFrame]]:
    return list(FleetSimulator(config).frames(n))


@pytest.fixture(scope="module")
def world() -> list[list[SensorFrame]]:
    return run(SimConfig(seed=7))


def test_same_seed_same_world_and_detections() -> None:
    a, b = run(SimConfig(seed=3), 25), run(SimConfig(seed=3), 25)
    for fa, fb in zip(a, b, strict=True):
        for x, y in zip(fa, fb, strict=True):
            assert (x.vehicle, x.sensor, x.seq, x.stamp) == (y.vehicle, y.sensor, y.seq, y.stamp)
            np.testing.assert_array_equal(x.pose, y.pose)
            np.testing.assert_array_equal(x.truth_ids, y.truth_ids)
            np.testing.assert_array_equal(x.truth.params, y.truth.params)
            np.testing.assert_array_equal(x.detections.params, y.detections.params)
            np.testing.assert_array_equal(x.detections.score, y.detections.score)
    c = run(SimConfig(seed=4), 25)
    assert not np.array_equal(a[-1][0].truth.params, c[-1][0].truth.params)


def test_objects_move_the_same_whatever_the_detector() -> None:
    noisy = SimConfig(seed=5, detector=DetectorModel(false_positives=5.0, centre_noise=1.0))
    a, b = run(SimConfig(seed=5), 20), run(noisy, 20)
    np.testing.assert_array_equal(a[-1][0].truth.params, b[-1][0].truth.params)
    assert not np.array_equal(a[-1][0].detections.params, b[-1][0].detections.params)


def test_every_vehicle_sensor_reports_every_frame_with_increasing_stamps(
    world: list[list[SensorFrame]],
) -> None:
    streams = {(f.vehicle, f.sensor) for f in world[0]}
    assert len(streams) == 3 * 2
    for k, frames in enumerate(world):
        assert {(f.vehicle, f.sensor) for f in frames} == streams
        assert all(f.seq == k and f.stamp == pytest.approx(k / 10) for f in frames)


def test_ground_truth_is_consistent(world: list[list[SensorFrame]]) -> None:
    sizes: dict[int, np.ndarray] = {}
    positions: dict[int, tuple[int, np.ndarray]] = {}
    max_speed = max(c.speed[1] for c in SimConfig().classes.values())
    for k, frames in enumerate(world):
        for f in frames:
            assert len(np.unique(f.truth_ids)) == len(f.truth_ids)
            assert f.truth_ignore.dtype == bool
            np.testing.assert_array_equal(f.truth_ignore, f.truth_occlusion > 0.8)
            # Truth is what lies inside the sensor's field of view and range.
            local = f.truth_in_sensor_frame
            r = np.hypot(local.x, local.y)
            spec = {s.name: s for s in SimConfig().sensors}[f.sensor]
            assert (r <= spec.max_range + 1e-9).all()
            assert (
                np.abs(np.arctan2(local.y, local.x)) <= math.radians(spec.fov_deg) / 2 + 1e-9
            ).all()
            for i, p in zip(f.truth_ids.tolist(), f.truth.params, strict=True):
                # An object keeps its size and moves no faster than its class allows.
                np.testing.assert_array_equal(sizes.setdefault(i, p[4:7]), p[4:7])
                if i in positions:
                    k0, p0 = positions[i]
                    step = np.hypot(*(p[:2] - p0[:2]))
                    assert step <= max_speed * (k - k0) / 10 + 1e-6
                positions[i] = (k, p)


def test_objects_enter_and_leave_the_views(world: list[list[SensorFrame]]) -> None:
    first_seen: dict[tuple[str, str], set[int]] = {}
    for f in world[0]:
        first_seen[(f.vehicle, f.sensor)] = set(f.truth_ids.tolist())
    entered = left = 0
    for f in world[-1]:
        now = set(f.truth_ids.tolist())
        before = first_seen[(f.vehicle, f.sensor)]
        entered += len(now - before)
        left += len(before - now)
    assert entered > 5 and left > 5


def _fleet_detector_stats(world: list[list[SensorFrame]]) -> dict[str, float]:
    truth_n = matched = fp = dup = low = high = 0
    for frames in world:
        for f in frames:
            det = f.detections
            truth = f.truth_in_sensor_frame
            truth_n += len(truth)
            high += int((det.score >= 0.7).sum())
            low += int((det.score < 0.5).sum())
            if len(det) == 0:
                continue
            if len(truth):
                iou = iou_3d(det.params, truth.params)
                best = iou.max(axis=1)
                matched += len(set(iou.argmax(axis=1)[best > 0.1].tolist()))
                fp += int((best < 0.01).sum())
            else:
                fp += len(det)
            same = (det.cls[:, None] == det.cls[None, :]) & ~np.eye(len(det), dtype=bool)
            dup += int(((iou_3d(det.params, det.params) > 0.25) & same).any(axis=1).sum())
    return {
        "recall": matched / truth_n,
        "fp": fp,
        "dup": dup,
        "low": low,
        "high": high,
        "frames": sum(len(frames) for frames in world),
    }


def test_detector_misses_duplicates_false_positives_and_low_scores(
    world: list[list[SensorFrame]],
) -> None:
    s = _fleet_detector_stats(world)
    assert 0.5 < s["recall"] < 0.95  # misses, but mostly sees
    assert s["fp"] > 0.3 * s["frames"]  # ~0.8 per sensor frame by default
    assert s["dup"] > 10  # overlapping same-class pairs for NMS to remove
    assert s["low"] > 0.05 * s["high"]  # material for the tracker's second stage


def test_a_hidden_object_is_missed_more() -> None:
    # Seen from the origin: a near car at 10 m hides a far one at 20 m straight behind it.
    local = Boxes.from_arrays(
        [[10, 0, 0, 0, 4, 2, 1.5], [20, 0, 0, 0, 4, 2, 1.5], [20, 15, 0, 0, 4, 2, 1.5]],
        [1, 1, 1],
        [0, 0, 0],
    )
    occ = occlusion(local)
    assert occ[0] == 0.0 and occ[2] == 0.0
    assert occ[1] == 1.0


def _detected(f: SensorFrame) -> np.ndarray:
    """Per truth object of the frame: did some same-class detection land within 1.5 m?"""
    truth, det = f.truth_in_sensor_frame, f.detections
    if len(truth) == 0 or len(det) == 0:
        return np.zeros(len(truth), dtype=bool)
    d = np.hypot(truth.x[:, None] - det.x[None, :], truth.y[:, None] - det.y[None, :])
    return np.asarray(((d < 1.5) & (truth.cls[:, None] == det.cls[None, :])).any(axis=1))


def _miss_runs(frames: list[list[SensorFrame]]) -> tuple[float, float]:
    """(miss rate, mean length of a run of consecutive misses) of the near, unhidden objects."""
    history: dict[tuple[str, str, int], list[tuple[int, bool]]] = {}
    for k, step in enumerate(frames):
        for f in step:
            hit = _detected(f)
            local = f.truth_in_sensor_frame
            near = np.hypot(local.x, local.y) < 20.0  # little range penalty: the chain shows
            clear = (f.truth_occlusion == 0.0) & near
            for i, h, c in zip(f.truth_ids.tolist(), hit.tolist(), clear.tolist(), strict=True):
                if c:
                    history.setdefault((f.vehicle, f.sensor, i), []).append((k, h))
    misses = total = 0
    runs: list[int] = []
    for seq in history.values():
        run, last_k = 0, -2
        for k, h in seq:
            if k != last_k + 1 and run:  # a gap (hidden or out of view) ends a run
                runs.append(run)
                run = 0
            total += 1
            if h:
                if run:
                    runs.append(run)
                run = 0
            else:
                misses += 1
                run += 1
            last_k = k
        if run:
            runs.append(run)
    return misses / total, float(np.mean(runs))


def test_misses_come_in_bursts_longer_than_independent_misses_give() -> None:
    rate, mean_run = _miss_runs(run(SimConfig(seed=7), 150))
    # Misses independent per frame with rate q give runs of mean 1 / (1 - q).
    # Measured on seed 7: rate 0.18, runs of 1.66 frames against 1.23 if independent; the
    # seen-state misses are single frames and dilute the lost spells' bursts.
    independent = 1.0 / (1.0 - rate)
    assert 0.05 < rate < 0.4, rate
    assert mean_run > 1.25 * independent, (mean_run, independent)
    # The same measurement on a detector that is never 'lost' finds no bursts: it can tell.
    never_lost = DetectorModel(seen_s=1e6, lost_s=0.01)
    rate, mean_run = _miss_runs(run(SimConfig(seed=7, detector=never_lost), 150))
    assert mean_run < 1.1 * (1.0 / (1.0 - rate)), (mean_run, rate)


def test_occluded_objects_are_missed_more(world: list[list[SensorFrame]]) -> None:
    clear_hits: list[bool] = []
    hidden_hits: list[bool] = []
    for step in world:
        for f in step:
            hit = _detected(f)
            clear_hits += hit[f.truth_occlusion == 0.0].tolist()
            hidden_hits += hit[f.truth_occlusion > 0.5].tolist()
    assert len(hidden_hits) > 100
    assert np.mean(hidden_hits) < 0.6 * np.mean(clear_hits), (
        np.mean(hidden_hits),
        np.mean(clear_hits),
    )


def test_config_errors_name_the_bad_value() -> None:
    with pytest.raises(ValidationError, match="vehicles"):
        SimConfig(vehicles=0)
    with pytest.raises(ValidationError, match="sensor names must be unique"):
        SimConfig(sensors=(SimConfig().sensors[0], SimConfig().sensors[0]))
    with pytest.raises(ValueError, match="not the first classes"):
        SimConfig().check_tracker_config(preset("kitti"))
    SimConfig().check_tracker_config(preset("wod"))


# The core tracker with the demo's settings (preset "wod" with the changes of
# simpletrack.sim.demo_tracker, chosen on seed 1), fed the pose so it tracks in the world frame,
# on 3 vehicles x 2 sensors x 150 frames of seed 11. Measured: MOTA 0.76 (IDS 402, 2.5 ids per
# object, recall 0.88, precision 0.91); preset "wod" as is: 0.56; the raw detections alone
# (score >= score_high, NMS, IDS not counted): 0.60. The floor leaves room for tracker changes
# and fails when tracking breaks or stops adding to the detections.
MOTA_FLOOR = 0.65


def test_core_tracker_tracks_the_simulated_fleet() -> None:
    from simpletrack.core.frames import Frame
    from simpletrack.core.tracker import Tracker
    from simpletrack.sim.baseline import detections_alone, without_identity
    from simpletrack.sim.demo_tracker import demo_tracker_config

    config = demo_tracker_config()
    sim = FleetSimulator(SimConfig(seed=11))
    sim.config.check_tracker_config(config)
    trackers = {s: Tracker(config) for s in sim.streams}
    scorers = {s: MotScorer() for s in sim.streams}
    alone = {s: MotScorer() for s in sim.streams}
    for frames in sim.frames(150):
        for f in frames:
            stream = (f.vehicle, f.sensor)
            out = trackers[stream].step(Frame(f.detections, f.stamp, f.pose))
            scorers[stream].update(f.truth_ids, f.truth, out.ids, out.boxes, f.truth_ignore)
            boxes = detections_alone(f.detections, f.pose, config)
            ids = np.arange(
                alone[stream].counts.frames * 1000, len(boxes) + alone[stream].counts.frames * 1000
            )
            alone[stream].update(f.truth_ids, f.truth, ids, boxes, f.truth_ignore)
    total = sum((s.counts for s in scorers.values()), MotCounts())
    baseline = without_identity(sum((s.counts for s in alone.values()), MotCounts()))
    assert total.gt > 5000
    assert total.mota > MOTA_FLOOR, total
    assert total.mota > baseline.mota + 0.05, (total.mota, baseline.mota)
    assert 1.0 < total.ids_per_object < 4.0, total
