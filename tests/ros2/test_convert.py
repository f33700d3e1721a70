"""DetectedObjects (made by rosbags) -> the service's detection frame; tracks -> TrackedObjects
(read back by rosbags)."""

from __future__ import annotations

import math
import uuid

import numpy as np
import pytest

from simpletrack.client.publisher import Box, box_list_to_arrays
from simpletrack.ros2.codec import decode_detected_objects, encode_tracked_objects
from simpletrack.ros2.convert import (
    ScoreSource,
    Skip,
    detections_to_boxes,
    tracks_to_tracked_objects,
)
from simpletrack.ros2.labels import label_map
from simpletrack.wire import (
    BoxArrays,
    Rejection,
    TrackArrays,
    decode_detection_frame,
    encode_detection_frame,
)
from tests.ros2 import rosmsgs as R

KITTI = ("Car", "Pedestrian", "Cyclist")


def _frame(boxes: BoxArrays, stamp_ns: int, frame_id: str) -> bytes:
    return encode_detection_frame(
        vehicle=R.FIXTURE_VEHICLE,
        sensor=R.FIXTURE_SENSOR,
        seq=R.FIXTURE_SEQ,
        stamp_ns=stamp_ns,
        frame_id=frame_id,
        boxes=boxes,
    )


def test_the_fixture_becomes_the_frame_the_python_encoder_makes() -> None:
    converted = detections_to_boxes(
        decode_detected_objects(R.fixture_cdr()), label_map("kitti"), KITTI
    )
    assert converted.stamp_ns == 1_700_000_000_000_000_000
    assert converted.frame_id == "base_link"
    assert not converted.skipped
    python = box_list_to_arrays(
        [Box(b.x, b.y, b.z, b.yaw, b.l, b.w, b.h, b.score, b.cls, b.vx, b.vy) for b in R.FIXTURE],
        KITTI,
    )
    ours = decode_detection_frame(_frame(converted.boxes, converted.stamp_ns, converted.frame_id))
    theirs = decode_detection_frame(_frame(python, R.FIXTURE_STAMP_S * 10**9, R.FIXTURE_FRAME))
    assert not isinstance(ours, Rejection) and not isinstance(theirs, Rejection)
    a, b = ours.boxes, theirs.boxes
    assert a.classes == b.classes == KITTI
    for name in ("class_index", "center", "size", "yaw", "score"):
        np.testing.assert_array_equal(getattr(a, name), getattr(b, name), err_msg=name)
    # The velocity goes into the object's frame (rosmsgs.object_frame_twist) and back: a zero
    # comes back as 5.6e-17, which float32 keeps. Everything else is bit for bit.
    assert a.velocity is not None and b.velocity is not None
    np.testing.assert_allclose(a.velocity, b.velocity, rtol=0, atol=1e-12)
    np.testing.assert_allclose(a.velocity, [[5, 0], [1, 0.5], [-3, 0.2]], atol=1e-6)
    header = {f: getattr(ours.frame, f) for f in ("vehicle", "sensor", "seq", "stamp_ns")}
    assert header == {"vehicle": "veh-fixture", "sensor": "lidar", "seq": 7,
                      "stamp_ns": 1_700_000_000 * 10**9}  # fmt: skip
    assert ours.frame.frame_id == theirs.frame.frame_id == "base_link"


def test_the_best_classification_decides_the_class() -> None:
    obj = R.detected_object(R.FIXTURE[0], classes=R.classification((1, 0.3), (7, 0.6), (6, 0.1)))
    msg = decode_detected_objects(R.serialize(R.detected_objects([obj])))
    out = detections_to_boxes(msg, label_map("kitti"), KITTI)
    assert out.boxes.class_names() == ["Pedestrian"]


def test_nuscenes_names_and_a_custom_map() -> None:
    labels = [2, 3, 4, 5, 6, 7, 1]
    objs = [R.detected_object(R.FIXTURE[0], classes=R.classification((lab, 1.0))) for lab in labels]
    msg = decode_detected_objects(R.serialize(R.detected_objects(objs)))
    names = ("car", "bus", "trailer", "truck", "pedestrian", "bicycle", "motorcycle")
    out = detections_to_boxes(msg, label_map("nuscenes"), names)
    assert out.boxes.class_names() == [
        "truck", "bus", "trailer", "motorcycle", "bicycle", "pedestrian", "car",
    ]  # fmt: skip
    custom = label_map("CAR=vehicle,TRUCK=vehicle,6=cyclist")
    out = detections_to_boxes(msg, custom, ("vehicle", "cyclist"))
    assert out.boxes.class_names() == ["vehicle", "cyclist", "vehicle"]
    assert out.unknown_labels == {3: 1, 4: 1, 5: 1, 7: 1}


def test_objects_that_cannot_be_boxes_are_left_out_and_counted() -> None:
    car, ped, far = R.FIXTURE
    objs = [
        R.detected_object(car),
        R.detected_object(ped, classes=[]),  # no classification
        R.detected_object(far, kind=1),  # a cylinder
        R.detected_object(far, kind=2),  # a polygon
        R.detected_object(car, classes=R.classification((2, 0.9))),  # TRUCK: not a KITTI class
        R.detected_object(ped, classes=R.classification((0, 0.9))),  # UNKNOWN
    ]
    msg = decode_detected_objects(R.serialize(R.detected_objects(objs)))
    out = detections_to_boxes(msg, label_map("kitti"), KITTI)
    assert out.boxes.class_names() == ["Car"]
    assert out.skipped == {Skip.NO_CLASSIFICATION: 1, Skip.NOT_A_BOX: 2, Skip.UNKNOWN_LABEL: 2}
    assert out.unknown_labels == {2: 1, 0: 1}


def test_velocity_is_sent_only_when_every_object_has_a_twist() -> None:
    objs = [R.detected_object(R.FIXTURE[0]), R.detected_object(R.FIXTURE[1], has_twist=False)]
    msg = decode_detected_objects(R.serialize(R.detected_objects(objs)))
    assert detections_to_boxes(msg, label_map("kitti"), KITTI).boxes.velocity is None


def test_score_is_existence_or_the_class_probability_where_existence_is_zero() -> None:
    car = R.FIXTURE[0]
    objs = [
        R.detected_object(car, existence=0.8, classes=R.classification((1, 0.5))),
        R.detected_object(car, existence=0.0, classes=R.classification((1, 0.375))),
    ]
    msg = decode_detected_objects(R.serialize(R.detected_objects(objs)))
    existence = detections_to_boxes(msg, label_map("kitti"), KITTI).boxes.score
    np.testing.assert_allclose(existence, [0.8, 0.375], rtol=1e-7)
    by_class = detections_to_boxes(msg, label_map("kitti"), KITTI, ScoreSource.CLASSIFICATION)
    np.testing.assert_allclose(by_class.boxes.score, [0.5, 0.375])


def test_an_empty_message_is_an_empty_frame() -> None:
    msg = decode_detected_objects(R.serialize(R.detected_objects([], sec=5, nanosec=7)))
    out = detections_to_boxes(msg, label_map("kitti"), KITTI)
    assert len(out.boxes) == 0 and out.stamp_ns == 5_000_000_007


@pytest.mark.parametrize("spec", ["", "CAR", "CAR=", "CAR=car,CAR=truck", "FOO=car", "300=car"])
def test_bad_label_maps_are_refused_naming_the_value(spec: str) -> None:
    with pytest.raises(ValueError, match=r"label|--labels"):
        label_map(spec)


# --- tracks -> TrackedObjects ------------------------------------------------------------------
def _tracks() -> TrackArrays:
    return TrackArrays(
        classes=KITTI,
        id=np.array([4, 9], np.int64),
        class_index=np.array([0, 1], np.int32),
        center=np.array([[10, 2, 0.8], [6, -3, 0.9]], np.float32),
        size=np.array([[4.5, 1.9, 1.6], [0.8, 0.7, 1.8]], np.float32),
        yaw=np.array([0.1, 1.5], np.float32),
        score=np.array([0.9, 0.7], np.float64),
        velocity=np.array([[5, 0, 0], [1, 0.5, 0.25]], np.float32),
        state=np.array([1, 0], np.int32),
        hits=np.array([5, 1], np.int32),
        age=np.array([5, 1], np.int32),
        time_since_update=np.array([0, 0], np.int32),
    )


def test_tracks_become_tracked_objects_rosbags_reads() -> None:
    t = _tracks()
    msg = tracks_to_tracked_objects(
        t,
        vehicle="veh-fixture",
        sensor="lidar",
        stamp_ns=1_700_000_000_250_000_000,
        frame_id="base_link",
        labels=label_map("kitti"),
    )
    out = R.deserialize(encode_tracked_objects(msg), R.TRACKED)
    assert (out.header.stamp.sec, out.header.stamp.nanosec) == (1_700_000_000, 250_000_000)
    assert out.header.frame_id == "base_link"
    for i, o in enumerate(out.objects):
        want = uuid.uuid5(uuid.NAMESPACE_URL, f"simpletrack:veh-fixture/lidar/{t.id[i]}")
        assert bytes(o.object_id.uuid) == want.bytes
        assert o.existence_probability == pytest.approx(t.score[i], rel=1e-7)
        assert [(c.label, c.probability) for c in o.classification] == [((1, 7)[i], 1.0)]
        p = o.kinematics.pose_with_covariance.pose
        np.testing.assert_allclose([p.position.x, p.position.y, p.position.z], t.center[i])
        q = p.orientation
        assert 2 * math.atan2(q.z, q.w) == pytest.approx(float(t.yaw[i]))
        lin = o.kinematics.twist_with_covariance.twist.linear
        yaw = float(t.yaw[i])
        world = (
            math.cos(yaw) * lin.x - math.sin(yaw) * lin.y,
            math.sin(yaw) * lin.x + math.cos(yaw) * lin.y,
        )
        np.testing.assert_allclose([*world, lin.z], t.velocity[i], atol=1e-6)
        assert o.kinematics.orientation_availability == 2
        assert not o.kinematics.pose_with_covariance.covariance.any()
        assert not o.kinematics.twist_with_covariance.covariance.any()
        assert o.shape.type == 0 and len(o.shape.footprint.points) == 0
        d = o.shape.dimensions
        np.testing.assert_allclose([d.x, d.y, d.z], t.size[i])


def test_version_2_covariance_fills_the_pose_and_twist_covariances() -> None:
    from dataclasses import replace

    from simpletrack.wire.columns import covariance_to_upper

    cov = np.zeros((2, 6, 6))
    cov[:] = np.diag([0.5, 0.25, 0.125, 4.0, 1.0, 2.0])
    cov[:, 3, 4] = cov[:, 4, 3] = 0.5
    t = replace(_tracks(), covariance=covariance_to_upper(cov))
    msg = tracks_to_tracked_objects(
        t, vehicle="v", sensor="s", stamp_ns=1, frame_id="f", labels=label_map("kitti")
    )
    out = R.deserialize(encode_tracked_objects(msg), R.TRACKED)
    for i, o in enumerate(out.objects):
        pose = np.asarray(o.kinematics.pose_with_covariance.covariance).reshape(6, 6)
        twist = np.asarray(o.kinematics.twist_with_covariance.covariance).reshape(6, 6)
        np.testing.assert_array_equal(pose[:3, :3], cov[i, :3, :3])
        assert not pose[3:].any() and not pose[:, 3:].any()  # orientation: not given
        # The twist is in the object's frame: its covariance turns with it, z unchanged.
        yaw = float(t.yaw[i])
        r = np.array([[math.cos(yaw), math.sin(yaw)], [-math.sin(yaw), math.cos(yaw)]])
        np.testing.assert_allclose(twist[:2, :2], r @ cov[i, 3:5, 3:5] @ r.T, atol=1e-6)
        assert twist[2, 2] == pytest.approx(2.0)
        assert not twist[3:].any() and not twist[:, 3:].any()


def test_a_class_outside_the_map_is_unknown() -> None:
    msg = tracks_to_tracked_objects(
        _tracks(), vehicle="v", sensor="s", stamp_ns=1, frame_id="f", labels=label_map("CAR=Car")
    )
    assert [o.classification[0].label for o in msg.objects] == [1, 0]
