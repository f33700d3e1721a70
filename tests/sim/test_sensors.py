"""Sensors with their own rates, latencies and detectors: frames at the right ticks, latency
on its own random stream, the vehicle's truth the union of its sensors' views, bad rates
refused by name."""

from __future__ import annotations

import math

import numpy as np
import pytest
from pydantic import ValidationError

from simpletrack.sim.fusion_sensors import fusion_sensors
from simpletrack.sim.simulator import (
    DetectorModel,
    FleetSimulator,
    SensorFrame,
    SensorSpec,
    SimConfig,
    default_sensors,
)

LIDAR = SensorSpec(name="lidar", rate_hz=10.0)
CAMERA = SensorSpec(name="cam", mount=(1.6, 0.0, 1.4, 0.0), fov_deg=90.0, max_range=75.0)


def two_rates(**camera: object) -> SimConfig:
    return SimConfig(
        seed=4,
        vehicles=2,
        sensors=(LIDAR, CAMERA.model_copy(update={"rate_hz": 15.0, **camera})),
    )


def ticks(config: SimConfig, n: int) -> list[list[SensorFrame]]:
    return list(FleetSimulator(config).frames(n))


def test_10_and_15_hz_tick_at_30_hz_each_stream_counting_its_own_frames() -> None:
    sim = FleetSimulator(two_rates())
    assert sim.base_hz == 30.0 and sim.dt == 1.0 / 30.0
    assert sim.ticks_per_frame == {"lidar": 3, "cam": 2}
    assert sim.streams == [
        ("veh00", "lidar"),
        ("veh00", "cam"),
        ("veh01", "lidar"),
        ("veh01", "cam"),
    ]
    seqs: dict[tuple[str, str], list[int]] = {s: [] for s in sim.streams}
    for k in range(13):
        assert sim.stamp == pytest.approx(k / 30.0)
        frames = sim.step()
        want = [s for s in ("lidar", "cam") if k % {"lidar": 3, "cam": 2}[s] == 0]
        assert [(f.vehicle, f.sensor) for f in frames] == [
            (v, s) for v in ("veh00", "veh01") for s in want
        ], k
        for f in frames:
            assert f.stamp == pytest.approx(k / 30.0)
            seqs[(f.vehicle, f.sensor)].append(f.seq)
    # Ticks 0..12: the lidar at 0, 3, 6, 9, 12; the camera at 0, 2, ..., 12; nothing at 1, 5, 7, 11.
    for (_, sensor), got in seqs.items():
        assert got == list(range(5 if sensor == "lidar" else 7)), (sensor, got)


def test_latency_is_drawn_within_its_bounds_in_stamp_order_and_changes_no_detection() -> None:
    plain = ticks(two_rates(), 90)
    late = ticks(two_rates(latency_s=(0.05, 0.15)), 90)
    published: dict[tuple[str, str], float] = {}
    latencies: list[float] = []
    for a_tick, b_tick in zip(plain, late, strict=True):
        for a, b in zip(a_tick, b_tick, strict=True):
            assert (a.vehicle, a.sensor, a.seq, a.stamp) == (b.vehicle, b.sensor, b.seq, b.stamp)
            np.testing.assert_array_equal(a.detections.params, b.detections.params)
            np.testing.assert_array_equal(a.detections.score, b.detections.score)
            np.testing.assert_array_equal(a.truth_ids, b.truth_ids)
            np.testing.assert_array_equal(a.vehicle_truth_ids, b.vehicle_truth_ids)
            assert a.latency_s == 0.0
            if b.sensor == "lidar":
                assert b.latency_s == 0.0
                continue
            assert 0.05 <= b.latency_s <= 0.15
            latencies.append(b.latency_s)
            # A stream's frames leave in the order they were taken.
            stream = (b.vehicle, b.sensor)
            assert b.stamp + b.latency_s >= published.get(stream, -math.inf)
            published[stream] = b.stamp + b.latency_s
    assert len(latencies) == 2 * 45
    assert np.std(latencies) > 0.02  # drawn, not a constant
    # Most draws stand as drawn; the wait for the frame before only raises the odd one.
    assert np.mean(latencies) == pytest.approx(0.1, abs=0.02)


def test_the_vehicle_truth_is_every_object_in_view_of_any_of_its_sensors() -> None:
    # The same base tick (30 Hz) gives the same world: with both sensors at 30 Hz every tick
    # has both frames, whose truths make the union the 10/15 Hz fleet must report at its ticks.
    fast = SimConfig(
        seed=4,
        vehicles=2,
        sensors=(
            LIDAR.model_copy(update={"rate_hz": 30.0}),
            CAMERA.model_copy(update={"rate_hz": 30.0}),
        ),
    )
    both = ticks(fast, 60)
    sparse = ticks(two_rates(), 60)
    threshold = fast.truth_ignore_occlusion
    checked_alone = 0
    for k, (full, frames) in enumerate(zip(both, sparse, strict=True)):
        by_vehicle = {f.vehicle: f for f in full}
        for v in ("veh00", "veh01"):
            own = [f for f in full if f.vehicle == v]
            least_hidden: dict[int, float] = {}
            for f in own:
                for i, occ in zip(f.truth_ids.tolist(), f.truth_occlusion.tolist(), strict=True):
                    least_hidden[i] = min(least_hidden.get(i, math.inf), occ)
            ref = by_vehicle[v]
            assert set(ref.vehicle_truth_ids.tolist()) == set(least_hidden)
            assert len(ref.vehicle_truth_ids) == len(least_hidden)
            want_ignore = [least_hidden[i] > threshold for i in ref.vehicle_truth_ids.tolist()]
            assert ref.vehicle_truth_ignore.tolist() == want_ignore
            for f in own:  # shared by the vehicle's frames of one stamp
                np.testing.assert_array_equal(f.vehicle_truth.params, ref.vehicle_truth.params)
        for f in frames:
            ref = by_vehicle[f.vehicle]
            np.testing.assert_array_equal(f.vehicle_truth_ids, ref.vehicle_truth_ids)
            np.testing.assert_array_equal(f.vehicle_truth.params, ref.vehicle_truth.params)
            np.testing.assert_array_equal(f.vehicle_truth_ignore, ref.vehicle_truth_ignore)
            assert not f.vehicle_truth_ids.flags.writeable
            if len({g.sensor for g in frames if g.vehicle == f.vehicle}) == 1:
                checked_alone += 1
                # Objects only the sensor without a frame now has in view are there too.
                assert set(f.vehicle_truth_ids.tolist()) > set(f.truth_ids.tolist()), k
    assert checked_alone > 20


def test_bad_rates_and_latencies_are_refused_naming_the_values() -> None:
    with pytest.raises(ValidationError, match=r"lidar 10 Hz, cam 15\.3 Hz.*1 ms.*1530 Hz"):
        two_rates(rate_hz=15.3)
    with pytest.raises(ValidationError, match=r"period of cam .* not a whole number of 1 s ticks"):
        SimConfig(
            sensors=(
                LIDAR.model_copy(update={"rate_hz": 1.0}),
                CAMERA.model_copy(update={"rate_hz": 1 / 3 + 1e-8}),
            )
        )
    with pytest.raises(ValidationError, match=r"latency_s \(0\.2, 0\.1\) must be \(min, max\)"):
        SensorSpec(name="cam", latency_s=(0.2, 0.1))
    for rate in (0.0, 2000.0):
        with pytest.raises(ValidationError, match="rate_hz"):
            SensorSpec(name="cam", rate_hz=rate)
    # Rates on a common tick of at least 1 ms are fine, whichever rates they are.
    assert FleetSimulator(two_rates(rate_hz=12.5)).ticks_per_frame == {"lidar": 5, "cam": 4}


def test_a_sensors_own_detector_changes_its_detections_only() -> None:
    noisy = DetectorModel(centre_noise=1.0, false_positives=5.0)
    a, b = ticks(two_rates(), 30), ticks(two_rates(detector=noisy), 30)
    changed = 0
    for a_tick, b_tick in zip(a, b, strict=True):
        for x, y in zip(a_tick, b_tick, strict=True):
            np.testing.assert_array_equal(x.truth.params, y.truth.params)
            if x.sensor == "lidar":
                np.testing.assert_array_equal(x.detections.params, y.detections.params)
            else:
                changed += not np.array_equal(x.detections.params, y.detections.params)
    assert changed > 10


def test_range_noise_lies_along_the_line_of_sight_and_grows_with_range() -> None:
    depth_only = DetectorModel(
        centre_noise=0.0,
        centre_noise_per_m=0.0,
        range_noise_per_m=0.03,
        duplicate_prob=0.0,
        false_positives=0.0,
    )
    config = SimConfig(seed=2, vehicles=1, objects=20, sensors=(LIDAR,), detector=depth_only)
    radial: list[float] = []
    ranges: list[float] = []
    for frames in ticks(config, 200):
        for f in frames:
            truth, det = f.truth_in_sensor_frame, f.detections
            for x, y in det.params[:, :2]:
                d = np.hypot(truth.x - x, truth.y - y)
                i = int(np.argmin(d))
                r = math.hypot(truth.x[i], truth.y[i])
                across = (truth.x[i] * y - truth.y[i] * x) / r  # offset across the sight line
                assert abs(across) < 1e-9
                radial.append((math.hypot(x, y) - r) / r)
                ranges.append(r)
    assert len(radial) > 500
    assert np.std(radial) == pytest.approx(0.03, rel=0.15)  # 3 % of range
    metres = np.array(radial) * np.array(ranges)
    far, near = np.array(ranges) > 30.0, np.array(ranges) < 15.0
    assert np.std(metres[far]) > 2.0 * np.std(metres[near])


def test_the_fusion_fleet_ticks_at_30_hz_with_its_documented_sensors() -> None:
    lidar, camera = fusion_sensors()
    assert (lidar.name, lidar.fov_deg, lidar.max_range, lidar.rate_hz) == (
        "lidar",
        360.0,
        50.0,
        10.0,
    )
    assert lidar.latency_s == (0.01, 0.03) and lidar.detector is None
    assert (camera.name, camera.rate_hz, camera.latency_s) == ("camera", 15.0, (0.05, 0.15))
    assert 90.0 <= camera.fov_deg <= 100.0 and 70.0 <= camera.max_range <= 80.0
    assert camera.detector is not None and camera.detector.range_noise_per_m > 0.0
    sim = FleetSimulator(SimConfig(sensors=fusion_sensors()))
    assert sim.ticks_per_frame == {"lidar": 3, "camera": 2}
    for frames in sim.frames(30):
        for f in frames:
            low, high = {"lidar": lidar, "camera": camera}[f.sensor].latency_s
            assert low <= f.latency_s <= high
    # The current demo's sensors stay as they were.
    assert [(s.name, s.fov_deg, s.max_range, s.rate_hz) for s in default_sensors()] == [
        ("lidar", 360.0, 50.0, None),
        ("front", 100.0, 70.0, None),
    ]
