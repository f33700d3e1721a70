"""A fused vehicle's bridge without a service: the frame table (which extrinsic or pose goes
with a message's header.frame_id), the keys of several inputs, fused tracks as
TrackedObjects (uuid of the fused global id, existence), the command line, and the bridge's
refusal of a frame it has no transform for (in process, on an unconnected session)."""

from __future__ import annotations

import argparse
import logging
import uuid
from collections.abc import Iterator
from dataclasses import replace

import numpy as np
import pytest

from simpletrack.cli.bridge import _plan
from simpletrack.cli.errors import UserError
from simpletrack.cli.main import build_parser
from simpletrack.ros2.bridge import FusedRos2Bridge
from simpletrack.ros2.codec import encode_tracked_objects
from simpletrack.ros2.convert import tracks_to_tracked_objects
from simpletrack.ros2.frames import IDENTITY, FrameMode, FrameTable, Placement, parse_extrinsic
from simpletrack.ros2.labels import label_map
from simpletrack.ros2.layout import Layout, fused_keys, graph_tokens
from simpletrack.session import open_session
from simpletrack.wire import TrackArrays
from tests.ros2 import rosmsgs as R

KITTI = ("Car", "Pedestrian", "Cyclist")
MOUNT = (1.0, 0.0, 0.0, 1.5, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 1.0, 1.8, 0.0, 0.0, 0.0, 1.0)
MOUNT_SPEC = "camera_front=" + ",".join(f"{v:g}" for v in MOUNT)


# --- frames ------------------------------------------------------------------------------------
def test_the_vehicle_frame_goes_with_the_identity_and_a_named_frame_with_its_extrinsic() -> None:
    table = FrameTable(extrinsics={"camera_front": MOUNT})
    assert table.mode is FrameMode.VEHICLE and table.output_frame == "base_link"
    assert table.place("base_link") == Placement(extrinsic=IDENTITY)
    assert table.place("camera_front") == Placement(extrinsic=MOUNT)
    assert table.place("camera_rear") is None  # never sent as if in the vehicle frame
    assert table.place("") is None
    assert table.describe() == "base_link (vehicle frame), camera_front (extrinsic)"
    assert tuple(np.eye(4).ravel()) == IDENTITY


def test_world_mode_takes_its_frame_only_with_the_identity_pose() -> None:
    table = FrameTable(world_frame="map")
    assert table.mode is FrameMode.WORLD and table.output_frame == "map"
    assert table.place("map") == Placement(pose=IDENTITY)
    assert table.place("base_link") is None  # the service refuses poses and extrinsics mixed


def test_tables_the_service_would_refuse_are_refused() -> None:
    with pytest.raises(ValueError, match="exclude each other"):
        FrameTable(extrinsics={"camera_front": MOUNT}, world_frame="map")
    with pytest.raises(ValueError, match="is the vehicle frame"):
        FrameTable(extrinsics={"base_link": MOUNT})


def test_an_extrinsic_is_a_frame_and_16_numbers_of_a_rigid_transform() -> None:
    assert parse_extrinsic(MOUNT_SPEC) == ("camera_front", MOUNT)
    assert parse_extrinsic("cam=" + " ".join(f"{v:g}" for v in MOUNT)) == ("cam", MOUNT)
    for bad, match in [
        ("camera_front", "FRAME=16 numbers"),
        ("=1,0", "FRAME=16 numbers"),
        ("cam=1,2,3", "3 numbers"),
        ("cam=" + ",".join(["x"] * 16), "not a list of numbers"),
        ("cam=" + ",".join(["nan"] * 16), "finite"),
        ("cam=" + ",".join(["2"] * 16), "--extrinsic cam"),  # not rigid
    ]:
        with pytest.raises(ValueError, match=match):
            parse_extrinsic(bad)


# --- keys --------------------------------------------------------------------------------------
def test_each_input_has_its_key_and_the_vehicle_one_output() -> None:
    keys = fused_keys(Layout.ROS2DDS, [("lidar", "/det/lidar"), ("camera", "det/camera")])
    assert [(i.sensor, i.topic, i.key) for i in keys.inputs] == [
        ("lidar", "/det/lidar", "det/lidar"),
        ("camera", "/det/camera", "det/camera"),
    ]
    assert keys.out_key == "perception/object_recognition/tracking/objects"
    rmw = fused_keys(Layout.RMW_ZENOH, [("lidar", "/a"), ("radar", "/b")], "/t", domain=2)
    assert rmw.inputs[1].key.startswith(
        "2/b/autoware_perception_msgs::msg::dds_::DetectedObjects_/"
    )
    node, lidar, radar, pub = graph_tokens(rmw, "aac3178e146ba6f1fc6e6a4085e77f21")
    assert node.endswith("/0/0/NN/%/%/simpletrack_bridge")
    assert [t.split("/")[4:6] for t in (lidar, radar, pub)] == [
        ["1", "MS"],
        ["2", "MS"],
        ["3", "MP"],
    ]
    assert [t.split("/")[9] for t in (lidar, radar, pub)] == ["%a", "%b", "%t"]


@pytest.mark.parametrize(
    ("inputs", "match"),
    [
        ([], "at least one input"),
        ([("lidar", "/a"), ("lidar", "/b")], "two inputs"),
        ([("lidar", "/a"), ("camera", "a")], "both on topic /a"),
        ([("lidar", "/perception/object_recognition/tracking/objects")], "output topic"),
        ([("lidar", "a b")], "topic"),
    ],
)
def test_inputs_that_cannot_work_are_refused(inputs: list[tuple[str, str]], match: str) -> None:
    with pytest.raises(ValueError, match=match):
        fused_keys(Layout.ROS2DDS, inputs)


# --- fused tracks -> TrackedObjects -------------------------------------------------------------
def test_fused_tracks_carry_the_uuid_of_their_global_id_and_their_existence() -> None:
    tracks = TrackArrays(
        classes=KITTI,
        id=np.array([3, 41], np.int64),
        class_index=np.array([0, 1], np.int32),
        center=np.array([[10, 2, 0.8], [6, -3, 0.9]], np.float32),
        size=np.array([[4.5, 1.9, 1.6], [0.8, 0.7, 1.8]], np.float32),
        yaw=np.array([0.1, 1.5], np.float32),
        score=np.array([0.9, 0.7], np.float64),
        velocity=np.zeros((2, 3), np.float32),
        state=np.array([1, 0], np.int32),
        hits=np.array([5, 1], np.int32),
        age=np.array([5, 1], np.int32),
        time_since_update=np.array([0, 0], np.int32),
    )
    fused = replace(tracks, existence=np.array([0.97, 0.25]))
    msg = tracks_to_tracked_objects(
        fused, vehicle="veh01", sensor="@vehicle", stamp_ns=5, frame_id="base_link",
        labels=label_map("kitti"),
    )  # fmt: skip
    out = R.deserialize(encode_tracked_objects(msg), R.TRACKED)
    assert [bytes(o.object_id.uuid) for o in out.objects] == [
        uuid.uuid5(uuid.NAMESPACE_URL, f"simpletrack:veh01/@vehicle/{i}").bytes for i in (3, 41)
    ]
    existence = [o.existence_probability for o in out.objects]
    np.testing.assert_allclose(existence, [0.97, 0.25], rtol=1e-7)  # not the score
    # The same track id of a sensor stream is another object, with another UUID.
    lidar = tracks_to_tracked_objects(
        tracks, vehicle="veh01", sensor="lidar", stamp_ns=5, frame_id="base_link",
        labels=label_map("kitti"),
    )  # fmt: skip
    assert lidar.objects[0].object_id != msg.objects[0].object_id
    assert lidar.objects[0].existence_probability == pytest.approx(0.9)


# --- command line ------------------------------------------------------------------------------
def _args(*argv: str) -> argparse.Namespace:
    return build_parser().parse_args(["bridge", "ros2", "--vehicle", "veh01", *argv])


def test_two_inputs_are_a_fused_vehicle_and_one_is_the_one_sensor_bridge() -> None:
    plan = _plan(_args("--input", "lidar=/det/lidar", "--input", "camera=/det/cam",
                       "--extrinsic", MOUNT_SPEC))  # fmt: skip
    assert plan.fused is not None and plan.single is None and plan.frames is not None
    assert [i.sensor for i in plan.fused.inputs] == ["lidar", "camera"]
    assert plan.frames.place("camera_front") == Placement(extrinsic=MOUNT)
    one = _plan(_args("--input", "lidar=/det/lidar"))
    assert one.fused is None and one.sensor == "lidar"
    assert one.single is not None and one.single.in_key == "det/lidar"
    forced = _plan(_args("--fused", "--sensor", "lidar", "--world-frame", "map"))
    assert forced.fused is not None and forced.frames is not None
    assert [(i.sensor, i.key) for i in forced.fused.inputs] == [
        ("lidar", "perception/object_recognition/detection/objects")
    ]
    assert forced.frames.mode is FrameMode.WORLD
    default = _plan(_args())  # unchanged: sensor "objects" on the default topic
    assert default.sensor == "objects" and default.single is not None
    assert default.single.in_key == "perception/object_recognition/detection/objects"


@pytest.mark.parametrize(
    ("argv", "match"),
    [
        (["--extrinsic", MOUNT_SPEC], "for a fused vehicle"),
        (["--world-frame", "map"], "for a fused vehicle"),
        (["--input", "lidar=/a", "--sensor", "lidar"], "leave out"),
        (["--input", "lidar=/a", "--input", "cam=/b", "--topic", "/c"], "leave out"),
        (["--fused", "--in-key", "a/b"], "--in-key is for one sensor"),
        (["--input", "lidar"], "SENSOR=TOPIC"),
        (["--input", "li dar=/a", "--input", "cam=/b"], "sensor id"),
        (["--fused", "--extrinsic", MOUNT_SPEC, "--extrinsic", MOUNT_SPEC], "given twice"),
        (["--fused", "--extrinsic", MOUNT_SPEC, "--world-frame", "map"], "exclude each other"),
    ],
)
def test_arguments_that_do_not_fit_together_are_refused(argv: list[str], match: str) -> None:
    with pytest.raises(UserError, match=match):
        _plan(_args(*argv))


# --- the bridge, in process --------------------------------------------------------------------
@pytest.fixture
def bridge() -> Iterator[FusedRos2Bridge]:
    session = open_session(mode="peer")
    b = FusedRos2Bridge(
        session,
        fused_keys(Layout.ROS2DDS, [("lidar", "/det/lidar"), ("camera", "/det/cam")]),
        vehicle="veh-fused",
        labels=label_map("kitti"),
        classes=KITTI,
        frames=FrameTable(extrinsics={"camera_front": MOUNT}),
        log_interval_s=3600,
    )
    yield b
    b.close()
    session.close()  # type: ignore[no-untyped-call]


def _msg(frame_id: str, k: int) -> bytes:
    return R.serialize(R.detected_objects([R.detected_object(R.FIXTURE[0])], nanosec=k,
                                          frame_id=frame_id))  # fmt: skip


@pytest.mark.zenoh
def test_a_frame_without_a_transform_is_refused_counted_and_logged_per_input(
    bridge: FusedRos2Bridge, caplog: pytest.LogCaptureFixture
) -> None:
    caplog.set_level(logging.WARNING, "simpletrack.ros2.bridge")
    assert bridge.handle(_msg("base_link", 0), sensor="lidar") == 0
    assert bridge.handle(_msg("camera_front", 0), sensor="camera") == 0
    assert bridge.handle(_msg("camera_rear", 1), sensor="camera") is None
    assert bridge.handle(_msg("camera_rear", 2), sensor="camera") is None
    assert bridge.handle(_msg("camera_front", 3), sensor="camera") == 1  # and it goes on
    assert bridge.handle(b"junk", sensor="lidar") is None
    s = bridge.stats
    assert (s.received, s.published) == (6, 3)
    assert s.refused == {"unknown_frame": 2, "bad_cdr": 1}
    assert s.inputs["camera"].refused == {"unknown_frame": 2}
    assert s.inputs["lidar"].refused == {"bad_cdr": 1}
    lines = [r.getMessage() for r in caplog.records if "frame refused" in r.getMessage()]
    assert len(lines) == 2  # one per input and reason within the interval
    assert "det/cam" in lines[0] and "--extrinsic camera_rear=" in lines[0]
    assert s.summary().endswith(
        "; lidar: 2 received, 1 published, 1 refused (bad_cdr 1), 0 refused by the service"
        "; camera: 4 received, 2 published, 2 refused (unknown_frame 2), 0 refused by the service"
    )
    with pytest.raises(ValueError, match="which input"):
        bridge.handle(_msg("base_link", 9))
