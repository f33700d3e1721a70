"""A demo recording with a ROS 2 bag (``demo --mcap FILE --ros2``), read by rosbags: a real
service fusing a lidar and a camera, so the bag
holds each sensor's DetectedObjects and TrackedObjects and the vehicle's fused TrackedObjects;
every TrackedObjects message decodes and matches the msgpack channel's tracks (the documented
uuid, positions within 1e-6), every DetectedObjects the detections (labels: the demo's
classes are the wod preset's)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import pytest
from mcap.reader import make_reader

from simpletrack.mcap.format import split_key
from simpletrack.mcap.ros2 import default_path
from simpletrack.sim.demo import DemoOptions, FleetDemo, ServiceMode
from simpletrack.sim.fusion_sensors import fusion_sensors
from simpletrack.sim.simulator import SimConfig
from tests.mcap.ros2_checks import DETECTED, TRACKED, check_detected, check_tracked, read_bag

pytestmark = pytest.mark.zenoh


def test_a_demo_recording_with_a_ros2_bag_reads_back_with_rosbags(tmp_path: Path) -> None:
    out = tmp_path / "demo.mcap"
    options = DemoOptions(
        sim=SimConfig(seed=4, vehicles=1, sensors=fusion_sensors()),
        duration=2.0,
        service=ServiceMode.INPROCESS,
        view_port=None,
        mcap=out,
        ros2=default_path(out),
        drain_s=1.0,
    )
    result = FleetDemo(options).run()
    assert result.unanswered == 0 and result.stats.tracked > 20

    raw: dict[str, list[Any]] = {}
    with open(out, "rb") as f:
        for _, channel, message in make_reader(f).iter_messages(log_time_order=True):
            if channel.message_encoding == "msgpack" and not channel.topic.endswith("/errors"):
                raw.setdefault(channel.topic, []).append(message)
    got = read_bag(default_path(out))
    topics: dict[str, list[Any]] = {}
    for m in got:
        topics.setdefault(m.topic, []).append(m)
    want = {}
    for key in raw:
        parts = split_key(key)
        assert parts is not None
        _, vehicle, sensor, leaf = parts
        names = [vehicle] if sensor == "@vehicle" else [vehicle, sensor]
        last = "detected_objects" if leaf == "detections" else "tracked_objects"
        want["/" + "/".join(["simpletrack", *names, last])] = (key, vehicle, sensor, leaf)
    assert set(topics) == set(want)
    assert "/simpletrack/veh00/tracked_objects" in topics  # the fused vehicle
    tracked = detected = 0
    for topic, (key, vehicle, sensor, leaf) in want.items():
        assert len(topics[topic]) == len(raw[key]), topic
        for message, recorded in zip(topics[topic], raw[key], strict=True):
            assert message.log_time == recorded.log_time
            if leaf == "tracks":
                assert message.msgtype == TRACKED
                tracked += check_tracked(message.msg, recorded.data, vehicle, sensor, "wod")
            else:
                assert message.msgtype == DETECTED
                detected += check_detected(message.msg, recorded.data, "wod")
    assert tracked > 50 and detected > 50
