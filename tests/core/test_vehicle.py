"""The vehicle tracker (core/vehicle.py): one sensor is the per-sensor tracker exactly; two
sensors give one id per object; what a sensor cannot see it cannot change; a sensor that
is not trusted cannot touch the tracks; late frames are re-processed into the state an
in-order run has."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import msgpack
import numpy as np
import pytest

from simpletrack.core.config import TrackerConfig, preset
from simpletrack.core.frames import Frame
from simpletrack.core.fusion_config import FusionConfig, SensorTrust
from simpletrack.core.lifecycle import UpdateKind
from simpletrack.core.tracker import STATE_FORMATS, Tracker
from simpletrack.core.vehicle import Condition, Outcome, SensorInput, VehicleTracker
from tests.core.fusion_helpers import (
    T0_NS,
    World,
    crossing,
    fusion,
    schedule,
    tracker_config,
)
from tests.core.helpers import models_config
from tests.core.test_step_kernels import _same, stream
from tests.core.test_step_kernels import configs as all_configs

DATA = Path(__file__).resolve().parents[3] / "shared" / "data"
ONE = FusionConfig(sensors={"lidar": SensorTrust()})


def _one_sensor_agrees(frames: list[Frame], config: object, period_ns: int) -> int:
    """Step a Tracker and a one-sensor VehicleTracker alike; returns the tracks compared."""
    tracker = Tracker(config)  # type: ignore[arg-type]
    vehicle = VehicleTracker(config, ONE)  # type: ignore[arg-type]
    n = 0
    for k, f in enumerate(frames):
        ns = T0_NS + k * period_ns
        plain = tracker.step(replace(f, stamp=(ns - T0_NS) * 1e-9))
        fused = vehicle.apply(
            SensorInput("lidar", k, ns, f.boxes, key_frame=f.key_frame, after_gap=f.after_gap)
        )
        assert fused.outcome is Outcome.APPLIED and fused.tracks is not None
        _same(plain, fused.tracks.tracks)
        assert fused.tracks.seq == k
        n += len(plain)
    return n


def configs() -> list[TrackerConfig]:
    """The step kernels' configurations a fused vehicle takes (not the motion models)."""
    return [
        c
        for c in all_configs()
        if c.state_dim == 10 and not any(k.revive_frames for k in c.classes.values())
    ]


def test_a_fused_vehicle_refuses_motion_models_and_lost_tracks_naming_the_class() -> None:
    with pytest.raises(ValueError, match="car: motion_model ctra, revive_frames 6"):
        VehicleTracker(models_config(), ONE)


@pytest.mark.parametrize("index", range(len(configs())))
def test_one_sensor_tracks_exactly_as_the_per_sensor_tracker(index: int) -> None:
    # Crowded streams with non-key frames and degenerate boxes, under every option set the
    # compiled step is held to.
    assert _one_sensor_agrees(stream(index % 2), configs()[index], 100_000_000) > 100


@pytest.mark.data
@pytest.mark.skipif(not (DATA / "kitti").is_dir(), reason="needs ../shared/data/kitti")
def test_one_sensor_tracks_kitti_exactly_as_the_per_sensor_tracker() -> None:
    from simpletrack.datasets.kitti import load_sequence

    config = preset("kitti")
    compared = 0
    for seq in ("0000", "0002", "0003", "0004", "0005", "0007", "0009", "0011", "0017", "0020"):
        seq_frames = load_sequence(DATA / "kitti", seq, config, config.class_names)
        frames = [Frame(f.boxes, f.stamp) for f in seq_frames]
        compared += _one_sensor_agrees(frames, config, 100_000_000)
    assert compared > 20_000


@pytest.mark.data
@pytest.mark.skipif(
    not (DATA / "nuscenes" / "centerpoint_val").is_dir(), reason="needs ../shared/data/nuscenes"
)
def test_one_sensor_tracks_nuscenes_exactly_as_the_per_sensor_tracker() -> None:
    from simpletrack.datasets.nuscenes import read_scene, scene_files

    config = preset("nuscenes")
    compared = 0
    for path in list(scene_files(DATA / "nuscenes" / "centerpoint_val"))[:10]:
        frames = [Frame(f.boxes, f.stamp) for f in read_scene(path, config.class_names)]
        compared += _one_sensor_agrees(frames, config, 500_000_000)
    assert compared > 40_000


def _run(
    world: World, vehicle: VehicleTracker, seconds: float, **frame: object
) -> dict[int, set[int]]:
    """Ids each car carried over the run (car: nearest to the track's box)."""
    carried: dict[int, set[int]] = {}
    for sensor, seq, t in schedule(seconds):
        r = vehicle.apply(world.frame(sensor, seq, t, **frame))  # type: ignore[arg-type]
        if r.tracks is None:
            continue
        truth = world.at(t)
        for i, b in zip(r.tracks.tracks.ids.tolist(), r.tracks.tracks.boxes.params, strict=True):
            car = int(np.argmin(np.hypot(*(truth - b[:2]).T)))
            carried.setdefault(car, set()).add(i)
    return carried


def test_every_car_has_one_id_whichever_sensors_see_it() -> None:
    world = crossing()
    carried = _run(world, VehicleTracker(tracker_config(), fusion()), 4.0)
    assert sorted(carried) == list(range(6))  # the camera-only car (62 m ahead) included
    assert all(len(ids) == 1 for ids in carried.values()), carried


def test_a_track_out_of_a_sensors_view_is_left_exactly_as_it_is() -> None:
    world = World(np.array([[-20.0, 0.0]]), np.array([[1.0, 0.0]]))  # behind: lidar only
    v = VehicleTracker(tracker_config(), fusion())
    v.apply(world.frame("lidar", 0, 0.0))
    before = v.tracker.tracks
    for k in range(1, 6):
        r = v.apply(world.frame("camera", k, k / 15))
        assert r.outcome is Outcome.APPLIED and r.tracks is not None
        assert r.tracks.tracks.ids.tolist() == before.ids.tolist()  # reported, predicted
    after = v.tracker.tracks
    for name in ("x", "p", "hits", "age", "time_since_update", "t_update", "score"):
        np.testing.assert_array_equal(getattr(before, name), getattr(after, name), err_msg=name)


def test_a_camera_that_misses_a_car_the_lidar_sees_kills_nothing() -> None:
    world = World(np.array([[20.0, 0.0]]), np.array([[0.0, 0.5]]))  # in both views
    v = VehicleTracker(tracker_config(max_age=2), fusion())
    ids: set[int] = set()
    for sensor, seq, t in schedule(3.0):
        seen = [sensor == "lidar"]  # the camera never detects it
        r = v.apply(world.frame(sensor, seq, t, seen=seen))
        assert r.tracks is not None
        ids |= set(r.tracks.tracks.ids.tolist())
    assert ids == {0}
    # Both miss it now: it dies once each has missed it max_age times.
    t = 3.0
    lived = 0
    for sensor, seq, dt in schedule(1.0):
        r = v.apply(world.frame(sensor, 100 + seq, t + dt, seen=[False]))
        if len(v):
            lived += 1
    assert len(v) == 0 and 3 <= lived <= 5


def test_a_sensor_that_may_not_start_tracks_starts_none() -> None:
    world = World(np.array([[62.0, 0.0]]), np.array([[0.0, 0.0]]))  # camera-only
    quiet = SensorTrust(fov_deg=90.0, max_range_m=70.0, verify=False, spawn=False)
    v = VehicleTracker(tracker_config(), fusion(camera=quiet))
    _run(world, v, 1.0)
    assert len(v) == 0
    v = VehicleTracker(tracker_config(), fusion())
    _run(world, v, 1.0)
    assert len(v) == 1


def test_existence_rises_with_detections_and_falls_with_misses_in_view() -> None:
    world = World(np.array([[20.0, 0.0]]), np.array([[0.0, 0.0]]))
    v = VehicleTracker(tracker_config(max_age=6, output="nuscenes"), fusion())
    seen = []
    for sensor, seq, t in schedule(1.0):
        r = v.apply(world.frame(sensor, seq, t, seen=[t < 0.5]))
        assert r.tracks is not None
        seen.append(float(r.tracks.existence[0]) if len(r.tracks.tracks) else 0.0)
    assert max(seen) > 0.99
    assert seen[-1] < 0.2  # half a second of misses by both sensors


def test_each_sensors_last_update_is_reported_per_track() -> None:
    world = crossing()
    v = VehicleTracker(tracker_config(), fusion())
    last = None
    for sensor, seq, t in schedule(1.0):
        r = v.apply(world.frame(sensor, seq, t))
        last = r.tracks or last
    assert last is not None
    stamps = last.sensor_stamp_ns
    assert stamps.shape == (len(last.tracks), 2)
    truth = world.at((last.stamp_ns - T0_NS) * 1e-9)
    car = [int(np.argmin(np.hypot(*(truth - b[:2]).T))) for b in last.tracks.boxes.params]
    for row, c in enumerate(car):
        lidar_saw, camera_saw = stamps[row] >= 0
        assert lidar_saw == (c != 4), (c, stamps[row])  # car 4: 62 m ahead, the camera's only
        seen = any(_sees(world, c, t) for s, _, t in schedule(1.0) if s == "camera")
        assert camera_saw == seen, (c, stamps[row])


def _sees(world: World, car: int, t: float) -> bool:
    """Whether the camera (1.5 m ahead, 90 degrees, 70 m) has the car in view at t."""
    x, y = world.at(t)[car] - (1.5, 0.0)
    return bool(np.hypot(x, y) <= 70.0 and abs(np.degrees(np.arctan2(y, x))) <= 45.0)


def test_a_sensor_under_verification_waits_until_it_agrees() -> None:
    world = crossing()
    verified = SensorTrust(fov_deg=90.0, max_range_m=70.0)  # verify: the default
    v = VehicleTracker(tracker_config(), fusion(camera=verified))
    outcomes = [v.apply(world.frame(s, seq, t)).outcome for s, seq, t in schedule(2.0)]
    camera = [o for (s, _, _), o in zip(schedule(2.0), outcomes, strict=True) if s == "camera"]
    assert camera[0] is Outcome.VERIFYING
    assert camera[-1] is Outcome.APPLIED
    assert v.records["camera"].condition is Condition.OK


def _lidar_only(world: World, seconds: float) -> VehicleTracker:
    v = VehicleTracker(tracker_config(), FusionConfig(sensors={"lidar": SensorTrust()}))
    for sensor, seq, t in schedule(seconds):
        if sensor == "lidar":
            v.apply(world.frame(sensor, seq, t))
    return v


def test_a_camera_mounted_20_m_off_is_flagged_and_changes_no_track() -> None:
    world = crossing()
    verified = SensorTrust(fov_deg=90.0, max_range_m=70.0)
    v = VehicleTracker(tracker_config(), fusion(camera=verified))
    outcomes = []
    for sensor, seq, t in schedule(3.0):
        r = v.apply(
            world.frame(sensor, seq, t, shift=(20.0, 0.0) if sensor == "camera" else (0, 0))
        )
        if sensor == "camera":
            outcomes.append(r.outcome)
    assert Outcome.APPLIED not in outcomes
    assert v.records["camera"].condition is Condition.EXTRINSIC
    assert "20." in v.records["camera"].detail
    alone = _lidar_only(world, 3.0)
    np.testing.assert_array_equal(v.tracker.tracks.ids, alone.tracker.tracks.ids)
    np.testing.assert_array_equal(v.tracker.tracks.x, alone.tracker.tracks.x)


def test_a_clock_ahead_of_the_services_is_flagged_and_kept_out() -> None:
    world = crossing()
    v = VehicleTracker(tracker_config(), fusion())
    for sensor, seq, t in schedule(1.0):
        lead = 5.0 if sensor == "camera" else 0.0
        r = v.apply(world.frame(sensor, seq, t, lead_s=lead))
        if sensor == "camera":
            assert r.outcome is Outcome.FLAGGED
    assert v.records["camera"].condition is Condition.CLOCK
    assert "5.000 s ahead" in v.records["camera"].detail


def test_a_clock_a_few_tenths_behind_is_flagged_from_the_residuals() -> None:
    # Every camera frame shows the cars 0.3 s later than its stamp says.
    world = World(
        np.array([[15.0, -20.0], [25.0, 20.0], [35.0, -25.0], [45.0, 20.0]]),
        np.array([[0.0, 8.0], [0.0, -8.0], [0.0, 9.0], [0.0, -7.0]]),
    )
    v = VehicleTracker(tracker_config(), fusion())
    for sensor, seq, t in schedule(2.5):
        capture = t + 0.3 if sensor == "camera" else None
        v.apply(world.frame(sensor, seq, t, capture_t=capture))
    rec = v.records["camera"]
    assert rec.condition is Condition.CLOCK, rec
    # Until it is flagged the camera's frames pull the tracks towards them: the estimate
    # comes out under the true offset, on its side of it.
    assert rec.delta_s is not None and 0.15 < rec.delta_s < 0.35


def test_a_late_frame_is_re_processed_into_the_in_order_state() -> None:
    world = crossing()
    frames = [world.frame(s, seq, t) for s, seq, t in schedule(2.0)]
    in_order = VehicleTracker(tracker_config(), fusion())
    for f in frames:
        in_order.apply(f)
    # The camera frame at 1.0 s arrives after the lidar frames up to 1.2 s.
    late = next(i for i, f in enumerate(frames) if f.sensor == "camera" and f.seq == 15)
    moved = [f for i, f in enumerate(frames) if i != late]
    at = next(i for i, f in enumerate(moved) if f.stamp_ns > frames[late].stamp_ns + 200_000_000)
    moved.insert(at, frames[late])
    v = VehicleTracker(tracker_config(), fusion())
    outcomes = [v.apply(f).outcome for f in moved]
    assert outcomes[at] is Outcome.REPROCESSED
    assert v.reprocessed > 0
    for name in ("ids", "x", "p", "hits", "age", "time_since_update", "state"):
        np.testing.assert_array_equal(
            getattr(v.tracker.tracks, name), getattr(in_order.tracker.tracks, name), err_msg=name
        )
    np.testing.assert_array_equal(v.cols.stamp_ns, in_order.cols.stamp_ns)


def test_a_frame_older_than_the_history_is_refused_late_and_repeated_ones_flag_the_clock() -> None:
    world = crossing()
    v = VehicleTracker(tracker_config(), fusion(history_s=0.2))
    for sensor, seq, t in schedule(2.0):
        if sensor == "lidar":
            v.apply(world.frame(sensor, seq, t))
    results = [v.apply(world.frame("camera", k, 0.5 + k / 15)) for k in range(3)]
    assert [r.outcome for r in results] == [Outcome.LATE] * 3
    assert "beyond history_s" in results[0].detail
    assert v.late == 3 and v.records["camera"].condition is Condition.CLOCK


def test_births_from_a_non_key_frame_never_happen_and_ids_are_consecutive() -> None:
    world = crossing()
    v = VehicleTracker(tracker_config(), fusion())
    f = world.frame("lidar", 0, 0.0)
    r = v.apply(replace(f, key_frame=False))
    assert r.tracks is not None and len(r.tracks.tracks) == 0
    r = v.apply(world.frame("lidar", 1, 0.1))
    assert r.tracks is not None
    assert sorted(r.tracks.tracks.ids.tolist()) == list(range(len(r.tracks.tracks)))
    assert (r.tracks.tracks.update == UpdateKind.MATCHED).all()


@pytest.mark.parametrize("state_format", STATE_FORMATS)
def test_the_state_continues_exactly_after_bytes(state_format: int) -> None:
    world = crossing()
    frames = [world.frame(s, seq, t) for s, seq, t in schedule(2.0)]
    whole = VehicleTracker(tracker_config(), fusion())
    outs = [whole.apply(f) for f in frames]
    half = VehicleTracker(tracker_config(), fusion())
    for f in frames[:20]:
        half.apply(f)
    blob = half.to_bytes(state_format)
    inner = msgpack.unpackb(msgpack.unpackb(blob, raw=False)["tracker"], raw=False)
    assert inner["format"] == state_format
    resumed = VehicleTracker.from_bytes(blob, tracker_config(), fusion())
    for f, want in zip(frames[20:], outs[20:], strict=True):
        got = resumed.apply(f)
        assert got.outcome is want.outcome
        if want.tracks is not None:
            assert got.tracks is not None and got.tracks.seq == want.tracks.seq
            _same(want.tracks.tracks, got.tracks.tracks)
            np.testing.assert_array_equal(want.tracks.existence, got.tracks.existence)


def test_a_state_of_other_sensors_is_refused() -> None:
    v = VehicleTracker(tracker_config(), fusion())
    with pytest.raises(ValueError, match="configured"):
        VehicleTracker.from_bytes(v.to_bytes(), tracker_config(), ONE)
