"""A fused vehicle through the ROS 2 bridge: a real service fusing a lidar and a camera
(tests/fusion_scenario.py), a real ``simpletrack bridge ros2 --input lidar=... --input
camera=...`` process, and a Zenoh session playing the ROS 2 side with DetectedObjects made by
rosbags. The lidar's objects come in the vehicle frame (``base_link``), the camera's in its
own frame (``camera_front``, mounted 1.5 m ahead: ``--extrinsic``). The bridge's one
TrackedObjects stream, read with rosbags, must be the fused tracks a ``VehicleTrackSubscriber``
receives (ids -> uuids, existence, boxes), and those the core's fused tracker gives on the
same frames: the camera's extrinsic went with its frames.

Topology: the bridge listens on its own endpoint and connects to the service; the ROS side
connects to the bridge, the planner to the service (peers do not route for each other)."""

from __future__ import annotations

import math
import threading
import time
import uuid
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import zenoh

from simpletrack.client import VehicleTrackMessage, VehicleTrackSubscriber
from simpletrack.ros2.layout import Layout, fused_keys
from simpletrack.session import open_session
from simpletrack.wire import BoxArrays, FrameError, Rejection, decode_message
from tests.core.fusion_helpers import CAMERA
from tests.fusion_scenario import VEHICLE, WireFrame, expected, frames, fusion_of, write_config
from tests.ros2 import rosmsgs as R
from tests.ros2.bridge_process import Bridge, start_bridge
from tests.service_helpers import start_service, wait_for

pytestmark = pytest.mark.zenoh

LIDAR_TOPIC = "/perception/object_recognition/detection/lidar/objects"
CAMERA_TOPIC = "/perception/object_recognition/detection/camera/objects"
FRAME_OF = {"lidar": "base_link", "camera": "camera_front"}
LABEL_OF = {"Car": 1, "Pedestrian": 7, "Cyclist": 6}


def detected_objects(f: WireFrame) -> bytes:
    """A scenario frame as the sensor's DetectedObjects, in its own frame."""
    b: BoxArrays = f.boxes
    objects = []
    for i in range(len(b)):
        cls = b.classes[int(b.class_index[i])]
        x, y, z = (float(v) for v in b.center[i])
        length, width, height = (float(v) for v in b.size[i])
        box = R.FixtureBox(cls, LABEL_OF[cls], x, y, z, length, width, height,
                           float(b.yaw[i]), float(b.score[i]), 0.0, 0.0)  # fmt: skip
        objects.append(R.detected_object(box, has_twist=False))
    sec, nanosec = divmod(f.stamp_ns, 10**9)
    return R.serialize(R.detected_objects(objects, sec, nanosec, FRAME_OF[f.sensor]))


class Sides:
    """The ROS side (on the bridge) and the planner (on the service)."""

    def __init__(self, bridge: Bridge, service_endpoint: str) -> None:
        keys = fused_keys(Layout.ROS2DDS, [("lidar", LIDAR_TOPIC), ("camera", CAMERA_TOPIC)])
        self.ros = open_session(mode="peer", connect=[bridge.endpoint])
        self.planner_session = open_session(mode="peer", connect=[service_endpoint])
        self.lock = threading.Lock()
        self.tracked: list[Any] = []
        self.errors: list[FrameError] = []
        self.publishers = {
            i.sensor: self.ros.declare_publisher(
                i.key, congestion_control=zenoh.CongestionControl.BLOCK
            )
            for i in keys.inputs
        }
        self.ros.declare_subscriber(keys.out_key, self._on_tracked)
        self.ros.declare_subscriber(f"fleet/{VEHICLE}/*/errors", self._on_error)
        self.planner = VehicleTrackSubscriber(self.planner_session, vehicle=VEHICLE)
        # An answer from the service comes after the subscriber's declaration reached it.
        wait_for(self._service_answers, 20, "the service, from the planner's session")
        for sensor, pub in self.publishers.items():
            wait_for(lambda p=pub: p.matching_status.matching, 20, f"the bridge's {sensor} input")

    def _service_answers(self) -> bool:
        replies = self.planner_session.liveliness().get("fleet/@simpletrack/*", timeout=1)
        return any(r.ok is not None for r in replies)

    def _on_tracked(self, sample: zenoh.Sample) -> None:
        msg = R.deserialize(sample.payload.to_bytes(), R.TRACKED)
        with self.lock:
            self.tracked.append(msg)

    def _on_error(self, sample: zenoh.Sample) -> None:
        err = decode_message(sample.payload.to_bytes(), FrameError)
        assert not isinstance(err, Rejection), err
        with self.lock:
            self.errors.append(err)

    def n(self) -> int:
        with self.lock:
            return len(self.tracked)

    def close(self) -> None:
        self.planner.close()
        for s in (self.ros, self.planner_session):
            s.close()  # type: ignore[no-untyped-call]


@pytest.fixture
def bridges() -> Iterator[list[Bridge]]:
    started: list[Bridge] = []
    yield started
    for b in started:
        b.kill()


def same(tracked: Any, msg: VehicleTrackMessage) -> None:
    """One TrackedObjects (rosbags) is the VehicleTrackFrame the planner got."""
    assert tracked.header.stamp.sec * 10**9 + tracked.header.stamp.nanosec == msg.stamp_ns
    assert tracked.header.frame_id == "base_link"
    uuids = [bytes(o.object_id.uuid) for o in tracked.objects]
    assert uuids == [uuid.uuid5(uuid.NAMESPACE_URL, "simpletrack:" + g).bytes
                     for g in msg.global_ids]  # fmt: skip
    t = msg.tracks
    for i, o in enumerate(tracked.objects):
        assert o.existence_probability == pytest.approx(msg.existence[i], rel=1e-6)
        assert [c.label for c in o.classification] == [LABEL_OF[msg.class_names()[i]]]
        p = o.kinematics.pose_with_covariance.pose
        np.testing.assert_array_equal([p.position.x, p.position.y, p.position.z], t.center[i])
        assert 2 * math.atan2(p.orientation.z, p.orientation.w) == pytest.approx(
            float(t.yaw[i]), abs=1e-6
        )
        d = o.shape.dimensions
        np.testing.assert_array_equal([d.x, d.y, d.z], t.size[i])


def test_two_sensors_in_one_tracked_objects_of_the_fused_tracks_out(
    tmp_path: Path, bridges: list[Bridge]
) -> None:
    config = write_config(tmp_path)
    wire = frames(2.0, time.time_ns() - 30 * 10**9)  # stamps behind the service's clock
    want = expected(wire, fusion_of(config))
    svc = start_service(tmp_path, "--config", str(config))
    try:
        extrinsic = ",".join(f"{v:g}" for v in CAMERA.ravel())
        bridge = start_bridge(
            bridges, tmp_path, svc, "--vehicle", VEHICLE,
            "--input", f"lidar={LIDAR_TOPIC}", "--input", f"camera={CAMERA_TOPIC}",
            "--extrinsic", f"camera_front={extrinsic}",
        )  # fmt: skip
        assert "frames taken: base_link (vehicle frame), camera_front (extrinsic)" in (
            bridge.stderr()
        )
        sides = Sides(bridge, svc.endpoint)
        try:
            for f in wire:  # in stamp order, both sensors interleaved
                sides.publishers[f.sensor].put(detected_objects(f))
                time.sleep(0.005)
            rear = R.detected_objects([], 1, 0, "camera_rear")  # a frame it has no transform for
            sides.publishers["camera"].put(R.serialize(rear))
            wait_for(lambda: sides.n() >= len(want), 30, "a TrackedObjects per fused message")
            wait_for(lambda: len(sides.errors) == 1, 10, "the refusal on the errors key")
            time.sleep(0.3)  # nothing more comes
            got = [sides.planner.try_recv() for _ in range(sides.planner.received)]
            messages = [m for m in got if m is not None]
            with sides.lock:
                tracked, errors = list(sides.tracked), list(sides.errors)
        finally:
            sides.close()
        rc, out = bridge.stop()
    finally:
        svc.stop()

    # The planner's messages are the core's fused tracks: the camera's frames went with
    # their extrinsic (without it, its boxes sit 1.5 m off and make tracks of their own).
    assert len(messages) == len(want) == len(tracked), (len(messages), len(want), len(tracked))
    for k, (m, w) in enumerate(zip(messages, want, strict=True)):
        assert m.seq == k
        np.testing.assert_array_equal(m.tracks.id, w.id, err_msg=str(k))
        np.testing.assert_allclose(m.tracks.center, w.center, atol=1e-4, err_msg=str(k))
        np.testing.assert_allclose(m.existence, w.existence, atol=1e-6, err_msg=str(k))
    assert {m.source[0] for m in messages} == {"lidar", "camera"}
    assert len({g for m in messages for g in m.global_ids}) >= 4  # cars seen by both and one
    # ... and the bridge's TrackedObjects are those messages, one for one.
    for t, m in zip(tracked, messages, strict=True):
        same(t, m)
    assert sum(len(t.objects) for t in tracked) > 0

    [err] = errors
    assert (err.sensor, err.reason.value, err.field) == ("camera", "missing_field", "extrinsic")
    assert "camera_rear" in err.detail and err.instance == f"ros2-bridge-{VEHICLE}-fused"
    assert rc == 0
    n = len(wire)
    lidar = sum(f.sensor == "lidar" for f in wire)
    assert f"{n + 1} DetectedObjects received, {n} frames published" in out
    assert "1 refused (unknown_frame 1)" in out
    assert f"{len(want)} TrackedObjects sent" in out
    assert f"lidar: {lidar} received, {lidar} published, 0 refused" in out
    assert f"camera: {n - lidar + 1} received, {n - lidar} published, 1 refused" in out
