"""A ``record --ros2`` bag read back by ``rosbags`` (the ROS 2 side's own reader: its MCAP
storage, its .msg parser on the bag's schemas, its CDR deserializer), each message checked
against the recording's msgpack channel decoded by the wire's decoder. The uuid rule is
computed here from its documentation (docs/ROS2.md), not by the bridge's function."""

from __future__ import annotations

import math
import uuid
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from rosbags.highlevel import AnyReader

from simpletrack.ros2.labels import label_map
from simpletrack.wire import (
    Rejection,
    decode_detection_frame,
    decode_track_frame,
    decode_vehicle_track_frame,
)
from simpletrack.wire.keys import VEHICLE_STREAM

DETECTED = "autoware_perception_msgs/msg/DetectedObjects"
TRACKED = "autoware_perception_msgs/msg/TrackedObjects"
POSITION_TOL = 1e-6


@dataclass
class BagMessage:
    topic: str
    msgtype: str
    log_time: int
    msg: Any
    raw: bytes


def read_bag(path: Path) -> list[BagMessage]:
    """Every message of the bag, deserialized by rosbags from the bag's own definitions."""
    out = []
    with AnyReader([path]) as reader:
        for connection, timestamp, raw in reader.messages():
            msg = reader.deserialize(raw, connection.msgtype)
            out.append(BagMessage(connection.topic, connection.msgtype, timestamp, msg, raw))
    return out


def documented_uuid(vehicle: str, sensor: str, track_id: int) -> bytes:
    """docs/ROS2.md: uuid5(NAMESPACE_URL, "simpletrack:<vehicle>/<sensor>/<track id>")."""
    return uuid.uuid5(uuid.NAMESPACE_URL, f"simpletrack:{vehicle}/{sensor}/{track_id}").bytes


def _yaw(q: Any) -> float:
    return math.atan2(2.0 * (q.w * q.z + q.x * q.y), 1.0 - 2.0 * (q.y * q.y + q.z * q.z))


def _angle(a: float, b: float) -> float:
    return abs(math.remainder(a - b, 2 * math.pi))


def _stamp(msg: Any) -> int:
    return int(msg.header.stamp.sec) * 1_000_000_000 + int(msg.header.stamp.nanosec)


def _f32(value: float) -> float:
    return float(np.float32(value))


def check_tracked(msg: Any, payload: bytes, vehicle: str, sensor: str, preset: str) -> int:
    """A TrackedObjects against the raw track frame it came from; the number of objects."""
    decoded = (
        decode_vehicle_track_frame(payload)
        if sensor == VEHICLE_STREAM
        else decode_track_frame(payload)
    )
    assert not isinstance(decoded, Rejection), decoded
    frame, t = decoded
    assert (_stamp(msg), msg.header.frame_id) == (frame.stamp_ns, frame.frame_id)
    assert len(msg.objects) == len(t)
    labels = label_map(preset)
    existence = t.score if t.existence is None else t.existence
    for i, obj in enumerate(msg.objects):
        assert bytes(obj.object_id.uuid) == documented_uuid(vehicle, sensor, int(t.id[i]))
        pose = obj.kinematics.pose_with_covariance.pose
        p = pose.position
        assert np.allclose([p.x, p.y, p.z], t.center[i], rtol=0, atol=POSITION_TOL)
        assert _angle(_yaw(pose.orientation), float(t.yaw[i])) < 1e-6
        d = obj.shape.dimensions
        assert [d.x, d.y, d.z] == t.size[i].tolist() and obj.shape.type == 0
        assert obj.existence_probability == _f32(existence[i])
        name = t.classes[t.class_index[i]]
        (c,) = obj.classification
        assert (c.label, c.probability) == (labels.label_of(name), 1.0)
        # The twist is in the object's frame: turned back by the yaw it is the velocity.
        lin = obj.kinematics.twist_with_covariance.twist.linear
        yaw = float(t.yaw[i])
        vx = math.cos(yaw) * lin.x - math.sin(yaw) * lin.y
        vy = math.sin(yaw) * lin.x + math.cos(yaw) * lin.y
        assert np.allclose([vx, vy, lin.z], t.velocity[i], rtol=0, atol=1e-5)
        assert obj.kinematics.orientation_availability == 2
        covariance = np.asarray(obj.kinematics.pose_with_covariance.covariance).reshape(6, 6)
        matrices = t.covariance_matrices()
        if matrices is None:
            assert not covariance.any()
        else:
            assert np.allclose(covariance[:3, :3], matrices[i][:3, :3], rtol=1e-6, atol=0)
    return len(t)


def check_detected(msg: Any, payload: bytes, preset: str) -> int:
    """A DetectedObjects against the raw detection frame it came from; the number of boxes."""
    decoded = decode_detection_frame(payload)
    assert not isinstance(decoded, Rejection), decoded
    b = decoded.boxes
    assert (_stamp(msg), msg.header.frame_id) == (decoded.frame.stamp_ns, decoded.frame.frame_id)
    assert len(msg.objects) == len(b)
    labels = label_map(preset)
    for i, obj in enumerate(msg.objects):
        pose = obj.kinematics.pose_with_covariance.pose
        p = pose.position
        assert np.allclose([p.x, p.y, p.z], b.center[i], rtol=0, atol=POSITION_TOL)
        assert _angle(_yaw(pose.orientation), float(b.yaw[i])) < 1e-6
        d = obj.shape.dimensions
        assert [d.x, d.y, d.z] == b.size[i].tolist()
        (c,) = obj.classification
        assert c.label == labels.label_of(b.classes[b.class_index[i]])
        assert c.probability == obj.existence_probability == _f32(b.score[i])
        assert obj.kinematics.has_twist == (b.velocity is not None)
        if b.velocity is not None:
            lin = obj.kinematics.twist_with_covariance.twist.linear
            yaw = float(b.yaw[i])
            vx = math.cos(yaw) * lin.x - math.sin(yaw) * lin.y
            vy = math.sin(yaw) * lin.x + math.cos(yaw) * lin.y
            assert np.allclose([vx, vy], b.velocity[i], rtol=0, atol=1e-5)
    return len(b)
