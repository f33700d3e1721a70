"""Our CDR against an independent serializer (rosbags): its bytes decode field by field, ours
deserialize with it field by field, and both make the same bytes."""

from __future__ import annotations

import contextlib
import math
import struct
from typing import Any

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from simpletrack.ros2.cdr import CdrError
from simpletrack.ros2.codec import (
    decode_detected_objects,
    decode_tracked_objects,
    encode_detected_objects,
    encode_tracked_objects,
)
from simpletrack.ros2.messages import (
    UUID,
    AccelWithCovariance,
    DetectedObjects,
    Header,
    ObjectClassification,
    Point,
    Point32,
    Polygon,
    Pose,
    PoseWithCovariance,
    Quaternion,
    Shape,
    Time,
    TrackedObject,
    TrackedObjectKinematics,
    TrackedObjects,
    Twist,
    TwistWithCovariance,
    Vector3,
)
from tests.ros2 import rosmsgs as R


def _rich_detected() -> Any:
    """Every field non-default: several classifications, a polygon, covariances, bools."""
    b = R.FIXTURE[0]
    obj = R.detected_object(b, classes=R.classification((1, 0.25), (2, 0.75)))
    obj.kinematics.pose_with_covariance.covariance[:] = R.cov(0.5)
    obj.kinematics.twist_with_covariance.covariance[:] = R.cov(-0.25)
    obj.kinematics.has_position_covariance = True
    obj.kinematics.has_twist_covariance = True
    obj.shape = R.shape(4.5, 1.9, 1.6, kind=2, footprint=((1.0, 2.0, 0.0), (-1.5, 0.5, 0.0)))
    ped = R.detected_object(R.FIXTURE[1], has_twist=False)
    return R.detected_objects([obj, ped], sec=1_700_000_123, nanosec=456_789, frame_id="map")


def _assert_same_detected(ours: DetectedObjects, theirs: Any) -> None:
    assert ours.header.stamp == Time(theirs.header.stamp.sec, theirs.header.stamp.nanosec)
    assert ours.header.frame_id == theirs.header.frame_id
    assert len(ours.objects) == len(theirs.objects)
    for o, t in zip(ours.objects, theirs.objects, strict=True):
        assert o.existence_probability == np.float32(t.existence_probability)
        assert [(c.label, c.probability) for c in o.classification] == [
            (c.label, float(np.float32(c.probability))) for c in t.classification
        ]
        k, tk = o.kinematics, t.kinematics
        p, tp = k.pose_with_covariance.pose, tk.pose_with_covariance.pose
        assert (p.position.x, p.position.y, p.position.z) == (
            tp.position.x,
            tp.position.y,
            tp.position.z,
        )
        q, tq = p.orientation, tp.orientation
        assert (q.x, q.y, q.z, q.w) == (tq.x, tq.y, tq.z, tq.w)
        assert k.pose_with_covariance.covariance == tuple(tk.pose_with_covariance.covariance)
        assert k.has_position_covariance == tk.has_position_covariance
        assert k.orientation_availability == tk.orientation_availability
        lin, tlin = k.twist_with_covariance.twist.linear, tk.twist_with_covariance.twist.linear
        assert (lin.x, lin.y, lin.z) == (tlin.x, tlin.y, tlin.z)
        assert k.twist_with_covariance.covariance == tuple(tk.twist_with_covariance.covariance)
        assert (k.has_twist, k.has_twist_covariance) == (tk.has_twist, tk.has_twist_covariance)
        assert o.shape.type == t.shape.type
        assert [(pt.x, pt.y, pt.z) for pt in o.shape.footprint.points] == [
            (float(np.float32(pt.x)), float(np.float32(pt.y)), float(np.float32(pt.z)))
            for pt in t.shape.footprint.points
        ]
        d, td = o.shape.dimensions, t.shape.dimensions
        assert (d.x, d.y, d.z) == (td.x, td.y, td.z)


@pytest.mark.parametrize("little_endian", [True, False])
def test_rosbags_detected_objects_decode_field_by_field(little_endian: bool) -> None:
    msg = _rich_detected()
    raw = bytes(R.typestore().serialize_cdr(msg, R.DETECTED, little_endian=little_endian))
    _assert_same_detected(decode_detected_objects(raw), msg)


def test_the_fixture_decodes_field_by_field() -> None:
    msg = R.detected_objects([R.detected_object(b) for b in R.FIXTURE])
    _assert_same_detected(decode_detected_objects(R.serialize(msg)), msg)


def test_our_detected_objects_bytes_are_rosbags_bytes() -> None:
    raw = R.serialize(_rich_detected())
    assert encode_detected_objects(decode_detected_objects(raw)) == raw


def _tracked() -> TrackedObjects:
    objects = []
    for i, b in enumerate(R.FIXTURE):
        yaw = b.yaw
        objects.append(
            TrackedObject(
                object_id=UUID(bytes(range(16 * i, 16 * i + 16))),
                existence_probability=b.score,
                classification=(ObjectClassification(b.label, 1.0),),
                kinematics=TrackedObjectKinematics(
                    pose_with_covariance=PoseWithCovariance(
                        Pose(
                            Point(b.x, b.y, b.z),
                            Quaternion(0.0, 0.0, math.sin(yaw / 2), math.cos(yaw / 2)),
                        ),
                        tuple(float(v) for v in range(36)),
                    ),
                    twist_with_covariance=TwistWithCovariance(
                        Twist(Vector3(b.vx, b.vy, 0.25), Vector3(0.0, 0.0, 0.125))
                    ),
                    acceleration_with_covariance=AccelWithCovariance(),
                    orientation_availability=2,
                    is_stationary=i == 1,
                ),
                shape=Shape(
                    0,
                    Polygon((Point32(0.5, -0.5, 0.0),)) if i == 2 else Polygon(),
                    Vector3(b.l, b.w, b.h),
                ),
            )
        )
    return TrackedObjects(Header(Time(1_700_000_000, 999_999_999), "base_link"), tuple(objects))


def test_our_tracked_objects_deserialize_with_rosbags_field_by_field() -> None:
    ours = _tracked()
    theirs = R.deserialize(encode_tracked_objects(ours), R.TRACKED)
    assert (theirs.header.stamp.sec, theirs.header.stamp.nanosec) == (1_700_000_000, 999_999_999)
    assert theirs.header.frame_id == "base_link"
    assert len(theirs.objects) == 3
    for o, t in zip(ours.objects, theirs.objects, strict=True):
        assert bytes(t.object_id.uuid) == o.object_id.uuid
        assert t.existence_probability == pytest.approx(o.existence_probability, rel=1e-7)
        assert [(c.label, c.probability) for c in t.classification] == [
            (o.classification[0].label, 1.0)
        ]
        k, tk = o.kinematics, t.kinematics
        tp = tk.pose_with_covariance.pose
        assert (tp.position.x, tp.position.y, tp.position.z) == (
            k.pose_with_covariance.pose.position.x,
            k.pose_with_covariance.pose.position.y,
            k.pose_with_covariance.pose.position.z,
        )
        assert tp.orientation.z == k.pose_with_covariance.pose.orientation.z
        assert tp.orientation.w == k.pose_with_covariance.pose.orientation.w
        assert tuple(tk.pose_with_covariance.covariance) == k.pose_with_covariance.covariance
        lin = tk.twist_with_covariance.twist.linear
        assert (lin.x, lin.y, lin.z) == (
            k.twist_with_covariance.twist.linear.x,
            k.twist_with_covariance.twist.linear.y,
            0.25,
        )
        assert tk.twist_with_covariance.twist.angular.z == 0.125
        assert not tk.acceleration_with_covariance.covariance.any()
        assert tk.orientation_availability == 2
        assert tk.is_stationary == k.is_stationary
        assert t.shape.type == 0
        assert (t.shape.dimensions.x, t.shape.dimensions.y, t.shape.dimensions.z) == (
            o.shape.dimensions.x,
            o.shape.dimensions.y,
            o.shape.dimensions.z,
        )
        assert len(t.shape.footprint.points) == len(o.shape.footprint.points)


def test_tracked_objects_bytes_equal_rosbags_and_round_trip() -> None:
    ours = _tracked()
    raw = encode_tracked_objects(ours)
    assert raw == R.serialize(R.deserialize(raw, R.TRACKED), R.TRACKED)
    back = decode_tracked_objects(raw)
    assert back.header == ours.header
    assert [o.object_id for o in back.objects] == [o.object_id for o in ours.objects]
    assert encode_tracked_objects(back) == raw


def test_detected_objects_round_trip() -> None:
    msg = decode_detected_objects(R.serialize(_rich_detected()))
    assert decode_detected_objects(encode_detected_objects(msg)) == msg


def test_an_empty_message_round_trips() -> None:
    raw = R.serialize(R.detected_objects([], sec=0, frame_id=""))
    msg = decode_detected_objects(raw)
    assert msg.objects == () and msg.header.frame_id == ""
    assert encode_detected_objects(msg) == raw


# --- refusals ---------------------------------------------------------------------------------
def test_every_truncation_is_a_cdr_error() -> None:
    raw = R.fixture_cdr()
    for n in range(len(raw) - 3):  # up to 3 bytes of padding may go missing
        with pytest.raises(CdrError):
            decode_detected_objects(raw[:n])


@pytest.mark.parametrize(
    ("mutate", "words"),
    [
        (lambda b: b"\x00\x07" + b[2:], "not plain CDR"),  # XCDR2 or garbage header
        (lambda b: b + b"\x00" * 8, "bytes left after the message"),
        (lambda b: b[:12] + struct.pack("<I", 0) + b[16:], "no NUL"),  # frame_id length 0
        (lambda b: b[:16] + b"\xff" + b[17:], "not UTF-8"),
        (lambda b: b[:28] + struct.pack("<I", 10**9) + b[32:], "cannot fit"),  # objects count
    ],
)
def test_malformed_payloads_are_refused_with_a_reason(mutate: Any, words: str) -> None:
    raw = R.fixture_cdr()
    # header 4 | stamp 8 | frame_id length 4 | "base_link\0" 10, padded to 28 | objects count
    assert raw[16:26] == b"base_link\x00"
    with pytest.raises(CdrError, match=words):
        decode_detected_objects(mutate(raw))


def test_a_bool_other_than_0_or_1_is_refused() -> None:
    msg = R.detected_objects([R.detected_object(R.FIXTURE[0])])
    raw = bytearray(R.serialize(msg))
    msg.objects[0].kinematics.has_position_covariance = True
    [cursor] = [i for i, (a, b) in enumerate(zip(raw, R.serialize(msg), strict=True)) if a != b]
    raw[cursor] = 2
    with pytest.raises(CdrError, match="neither 0 nor 1"):
        decode_detected_objects(bytes(raw))


@settings(max_examples=300, deadline=None)
@given(st.binary(max_size=2048))
def test_random_bytes_never_raise_anything_but_cdr_error(data: bytes) -> None:
    with contextlib.suppress(CdrError):
        decode_detected_objects(b"\x00\x01\x00\x00" + data)
