"""``record --format mcap --ros2``: the recorder also writes a ROS 2 bag (MCAP, profile ros2)
of Autoware DetectedObjects and TrackedObjects, converted as the ROS 2 bridge does, which
rosbags reads back: schemas as rosbag2 writes them (the .msg files with their dependencies),
topics a ROS user expects, every message equal to the recording's msgpack one. A sensor's
tracks, a fused vehicle's and detections, without a service (the real runs:
tests/cli/test_record_mcap_foxglove.py, and the demo's in test_ros2_demo.py)."""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import msgpack
import numpy as np
import pytest
from mcap.reader import make_reader
from rosbags.typesys import Stores, get_types_from_msg, get_typestore

from simpletrack.cli.errors import UserError
from simpletrack.cli.replay_mcap import load
from simpletrack.mcap.ros2 import (
    QOS_PROFILES,
    Ros2Bag,
    default_path,
    message_definition,
    ros_name,
)
from simpletrack.mcap.writer import McapRecorder
from simpletrack.ros2.codec import decode_detected_objects
from simpletrack.ros2.convert import detections_to_boxes
from simpletrack.ros2.labels import PRESET_LABELS, label_map
from simpletrack.ros2.recording import AutowareMessages, preset_labels
from simpletrack.ros2.typehash import MSG_DIR, type_hash
from simpletrack.wire import TrackArrays, encode_detection_frame, encode_track_frame
from simpletrack.wire.columns import BoxArrays, covariance_to_upper
from tests.mcap.ros2_checks import DETECTED, TRACKED, check_detected, check_tracked, read_bag
from tests.mcap.test_fused import vehicle_frame
from tests.mcap.test_writer import _Payload, _Sample
from tests.service_helpers import stamp

KITTI = ("Car", "Pedestrian", "Cyclist")
VEHICLE, SENSOR = "veh-01", "0100"  # names a ROS topic cannot hold as they are
FRAMES = 4


def boxes(k: int) -> BoxArrays:
    """A car, a pedestrian and a cyclist, each with its own heading and velocity."""
    return BoxArrays(
        classes=KITTI,
        class_index=np.int32([0, 1, 2]),
        center=np.float32([[10 + k, 2, 0.8], [5, -3 + 0.1 * k, 0.9], [20, 5, 0.85]]),
        size=np.float32([[4.2, 1.8, 1.5], [0.8, 0.7, 1.8], [1.8, 0.6, 1.7]]),
        yaw=np.float32([0.3, math.pi / 2, -2.5]),
        score=np.float64([0.91, 0.62, 0.77]),
        velocity=np.float32([[10, 3], [0, 1], [-4, -3]]),
    )


def tracks(k: int) -> TrackArrays:
    b = boxes(k)
    n = len(b)
    cov = np.tile(np.diag([0.5, 0.6, 0.1, 2.0, 2.5, 0.2]).astype(np.float32), (n, 1, 1))
    cov[:, 0, 1] = cov[:, 1, 0] = 0.05
    return TrackArrays(
        classes=b.classes,
        id=np.int64([3, 8, 21]),
        class_index=b.class_index,
        center=b.center,
        size=b.size,
        yaw=b.yaw,
        score=b.score,
        velocity=np.float32([[10, 3, 0], [0, 1, 0], [-4, -3, 0.5]]),
        state=np.int32([1, 0, 2]),
        hits=np.int32([k + 1, 1, 3]),
        age=np.int32([k + 1, 1, 4]),
        time_since_update=np.int32([0, 0, 1]),
        covariance=covariance_to_upper(cov),
        age_s=np.float64([0.1 * k, 0.0, 0.3]),
        time_since_update_s=np.float64([0.0, 0.0, 0.1]),
    )


def detections_payload(k: int) -> bytes:
    return encode_detection_frame(
        vehicle=VEHICLE, sensor=SENSOR, seq=k, stamp_ns=stamp(k), frame_id="lidar", boxes=boxes(k)
    )


def tracks_payload(k: int) -> bytes:
    return encode_track_frame(
        vehicle=VEHICLE, sensor=SENSOR, seq=k, stamp_ns=stamp(k), frame_id="map", pose=None,
        key_frame=True, instance="a", received_ns=stamp(k) + 1, published_ns=stamp(k) + 2,
        tracks=tracks(k),
    )  # fmt: skip


def damaged_detections() -> bytes:
    frame = msgpack.unpackb(detections_payload(FRAMES))
    frame["boxes"]["count"] = 5  # the columns hold 3 rows
    return msgpack.packb(frame)


@pytest.fixture(scope="module")
def recorded(tmp_path_factory: pytest.TempPathFactory) -> Iterator[tuple[Path, Path, Ros2Bag]]:
    out = tmp_path_factory.mktemp("ros2") / "field.mcap"
    bag = Ros2Bag(default_path(out), "fleet", AutowareMessages())
    recorder = McapRecorder(out, "fleet", ros2=bag)
    key = f"fleet/{VEHICLE}/{SENSOR}"
    for k in range(FRAMES):
        recorder.on_sample(_Sample(f"{key}/detections", _Payload(detections_payload(k))))
        recorder.on_sample(_Sample(f"{key}/tracks", _Payload(tracks_payload(k))))
        recorder.on_sample(_Sample("fleet/veh01/@vehicle/tracks", _Payload(vehicle_frame(k))))
    recorder.on_sample(_Sample(f"{key}/detections", _Payload(damaged_detections())))
    recorder.on_sample(_Sample(f"{key}/errors", _Payload(b"\x80")))
    recorder.close()
    yield out, bag.path, bag


def raw_messages(path: Path) -> dict[str, list[bytes]]:
    out: dict[str, list[bytes]] = {}
    with open(path, "rb") as f:
        for _, channel, message in make_reader(f).iter_messages(log_time_order=True):
            if channel.message_encoding == "msgpack":
                out.setdefault(channel.topic, []).append(message.data)
    return out


TOPICS = {
    "/simpletrack/veh_01/_0100/detected_objects": (
        f"fleet/{VEHICLE}/{SENSOR}/detections",
        DETECTED,
    ),
    "/simpletrack/veh_01/_0100/tracked_objects": (f"fleet/{VEHICLE}/{SENSOR}/tracks", TRACKED),
    "/simpletrack/veh01/tracked_objects": ("fleet/veh01/@vehicle/tracks", TRACKED),
}


def test_the_bag_is_a_ros2_mcap_file_of_its_own(recorded: tuple[Path, Path, Ros2Bag]) -> None:
    out, path, bag = recorded
    assert path == out.with_name("field.ros2.mcap")
    assert (bag.messages, bag.skipped) == (3 * FRAMES, 1)  # the damaged frame has no message
    with open(path, "rb") as f:
        reader = make_reader(f)
        assert reader.get_header().profile == "ros2"
        summary = reader.get_summary()
        metadata = {m.name: dict(m.metadata) for m in reader.iter_metadata()}
    assert summary is not None
    assert metadata["simpletrack"]["tool"] == "simpletrack record"
    assert "preset" in metadata["simpletrack"]["labels"]
    channels = {c.topic: c for c in summary.channels.values()}
    assert set(channels) == set(TOPICS)
    for topic, (_, type_name) in TOPICS.items():
        channel = channels[topic]
        schema = summary.schemas[channel.schema_id]
        assert (channel.message_encoding, schema.encoding, schema.name) == (
            "cdr",
            "ros2msg",
            type_name,
        )
        assert schema.data.decode() == message_definition(type_name, MSG_DIR)
        assert channel.metadata == {
            "offered_qos_profiles": QOS_PROFILES,
            "topic_type_hash": type_hash(type_name),
        }
        assert summary.statistics is not None
        assert summary.statistics.channel_message_counts[channel.id] == FRAMES
    # The recording itself names its bag and holds every raw message, the damaged one too.
    with open(out, "rb") as f:
        reader = make_reader(f)
        metadata = {m.name: dict(m.metadata) for m in reader.iter_metadata()}
    assert metadata["simpletrack"]["ros2"] == "field.ros2.mcap"
    assert len(raw_messages(out)[f"fleet/{VEHICLE}/{SENSOR}/detections"]) == FRAMES + 1


def test_rosbags_reads_every_message_equal_to_the_recorded_frame(
    recorded: tuple[Path, Path, Ros2Bag],
) -> None:
    out, path, _ = recorded
    raw = raw_messages(out)
    got = read_bag(path)
    assert {m.topic for m in got} == set(TOPICS)
    for topic, (key, type_name) in TOPICS.items():
        mine = [m for m in got if m.topic == topic]
        assert len(mine) == FRAMES and {m.msgtype for m in mine} == {type_name}
        vehicle, sensor = key.split("/")[1:3]
        for message, payload in zip(mine, raw[key], strict=False):
            if type_name == DETECTED:
                assert check_detected(message.msg, payload, "kitti") == 3
            else:
                assert check_tracked(message.msg, payload, vehicle, sensor, "kitti") == 2 + (
                    sensor != "@vehicle"
                )
    # A fused track's existence probability is its existence, a sensor track's its score.
    fused = [m.msg for m in got if m.topic == "/simpletrack/veh01/tracked_objects"]
    assert [o.existence_probability for o in fused[0].objects] == [
        float(np.float32(0.97)),
        float(np.float32(0.5)),
    ]


def test_the_bridge_reads_the_detected_objects_back_to_the_frames_boxes(
    recorded: tuple[Path, Path, Ros2Bag],
) -> None:
    """DetectedObjects here are what ``simpletrack bridge ros2`` takes: its reader turns them
    into the recorded boxes again (a bag replayed through a bridge feeds the same frames)."""
    _, path, _ = recorded
    mine = [m for m in read_bag(path) if m.msgtype == DETECTED]
    for k, message in enumerate(mine):
        converted = detections_to_boxes(
            decode_detected_objects(message.raw), label_map("kitti"), KITTI
        )
        got, want = converted.boxes, boxes(k)
        assert converted.stamp_ns == stamp(k) and converted.frame_id == "lidar"
        assert got.class_names() == want.class_names()
        np.testing.assert_array_equal(got.center, want.center)
        np.testing.assert_array_equal(got.size, want.size)
        np.testing.assert_allclose(got.yaw, want.yaw, atol=1e-6)
        np.testing.assert_allclose(got.score, want.score, rtol=1e-6)
        assert got.velocity is not None
        np.testing.assert_allclose(got.velocity, want.velocity, atol=1e-5)


def test_the_schema_text_is_what_rosbag2_writes() -> None:
    """The .msg file as it is, then each type it uses (sorted, depth first, once) after a line
    of 80 '=' and ``MSG: pkg/Name``; rosbags parses it into the very types the bridge hashes."""
    for type_name in (DETECTED, TRACKED):
        text = message_definition(type_name, MSG_DIR)
        own = (MSG_DIR / "autoware_perception_msgs" / f"{type_name.split('/')[-1]}.msg").read_text()
        assert text.startswith(own + "\n" + "=" * 80 + "\nMSG: ")
        names = [line[5:] for line in text.splitlines() if line.startswith("MSG: ")]
        assert len(names) == len(set(names))
        assert "std_msgs/Header" in names and "builtin_interfaces/Time" in names
        types: dict[str, Any] = {}
        for part in text.split("=" * 80 + "\n"):
            head, _, body = part.partition("\n")
            if head.startswith("MSG: "):
                pkg, name = head[5:].split("/")
                types.update(get_types_from_msg(body, f"{pkg}/msg/{name}"))
            else:
                types.update(get_types_from_msg(part, type_name))
        store = get_typestore(Stores.EMPTY)
        store.register(types)
        assert store.hash_rihs01(type_name) == type_hash(type_name)
    tracked = message_definition(TRACKED, MSG_DIR)
    names = [line[5:] for line in tracked.splitlines() if line.startswith("MSG: ")]
    # Depth first: TrackedObject's own types follow it, before std_msgs/Header (sorted last).
    assert names[0] == "autoware_perception_msgs/TrackedObject"
    assert names[-2:] == ["std_msgs/Header", "builtin_interfaces/Time"]


def test_names_become_ros_names_and_streams_keep_their_own_topics(tmp_path: Path) -> None:
    assert [ros_name(n) for n in ("veh01", "veh-01", "lidar.top", "0100", "a__b", "_x")] == [
        "veh01",
        "veh_01",
        "lidar_top",
        "_0100",
        "a_b",
        "_x",
    ]
    bag = Ros2Bag(tmp_path / "b.ros2.mcap", "fleet", AutowareMessages())
    try:
        assert (
            bag.topic("veh01", "lidar", "detections") == "/simpletrack/veh01/lidar/detected_objects"
        )
        assert bag.topic("veh01", "lidar", "tracks") == "/simpletrack/veh01/lidar/tracked_objects"
        assert bag.topic("veh01", "@vehicle", "tracks") == "/simpletrack/veh01/tracked_objects"
        # veh.1 and veh-1 would meet on veh_1: the later stream gets a name of its own, kept.
        assert bag.topic("veh.1", "lidar", "tracks") == "/simpletrack/veh_1/lidar/tracked_objects"
        assert bag.topic("veh-1", "lidar", "tracks") == "/simpletrack/veh_1/lidar_2/tracked_objects"
        assert bag.topic("veh-1", "lidar", "detections") == (
            "/simpletrack/veh_1/lidar_2/detected_objects"
        )
        assert bag.topic("veh.1", "lidar", "tracks") == "/simpletrack/veh_1/lidar/tracked_objects"
    finally:
        bag.close()


def test_labels_come_from_the_preset_the_classes_name_or_from_the_map_given() -> None:
    for preset, labels in PRESET_LABELS.items():
        classes = tuple(dict.fromkeys(labels.values()))
        assert preset_labels(classes).name == preset, preset
    assert preset_labels(("car", "pedestrian")).name == "nuscenes"
    assert preset_labels(("vehicle", "pedestrian", "cyclist")).name == "wod"  # the demo's
    auto = AutowareMessages()
    assert auto.labels_for(("Car", "Pedestrian")).label_of("Pedestrian") == 7
    fixed = AutowareMessages("CAR=Car,9=Cone")
    assert fixed.labels_for(KITTI).label_of("Cone") == 9
    assert fixed.labels_for(KITTI).label_of("Pedestrian") == 0  # UNKNOWN outside the map
    with pytest.raises(ValueError, match="--labels"):
        AutowareMessages("nonsense")


def test_a_custom_label_map_reaches_the_messages(tmp_path: Path) -> None:
    bag = Ros2Bag(tmp_path / "c.ros2.mcap", "fleet", AutowareMessages("BUS=Car"))
    recorder = McapRecorder(tmp_path / "c.mcap", "fleet", foxglove=False, ros2=bag)
    recorder.on_sample(_Sample(f"fleet/{VEHICLE}/{SENSOR}/tracks", _Payload(tracks_payload(0))))
    recorder.close()
    (message,) = read_bag(bag.path)
    assert [o.classification[0].label for o in message.msg.objects] == [3, 0, 0]


def test_replay_mcap_never_takes_the_bag_for_a_recording(
    recorded: tuple[Path, Path, Ros2Bag],
) -> None:
    _, path, _ = recorded
    with pytest.raises(UserError, match="ROS 2 bag"):
        load(path, None)


def test_the_cli_refuses_ros2_mistakes_in_one_line(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    from tests.cli.test_replay_record import one_line_error

    out = str(tmp_path / "r.mcap")
    base = ("record", "--format", "mcap", "--out", out)
    assert "--format mcap only" in one_line_error(
        capsys, "record", "--out", str(tmp_path / "j"), "--ros2"
    )
    assert "--ros2-labels applies with --ros2" in one_line_error(
        capsys, *base, "--ros2-labels", "kitti"
    )
    assert "LABEL=class" in one_line_error(capsys, *base, "--ros2", "--ros2-labels", "CAR")
    assert "--out" in one_line_error(capsys, *base, "--ros2", out)
    assert "existing folder" in one_line_error(
        capsys, *base, "--ros2", str(tmp_path / "no" / "b.mcap")
    )


def test_a_track_frame_of_version_1_converts_too(tmp_path: Path) -> None:
    """Before ages in seconds and covariances: the same objects, zero covariance."""
    t = dataclasses.replace(tracks(0), covariance=None, age_s=None, time_since_update_s=None)
    payload = encode_track_frame(
        vehicle="v", sensor="s", seq=0, stamp_ns=stamp(0), frame_id="map", pose=None,
        key_frame=True, instance="a", received_ns=1, published_ns=2, tracks=t,
    )  # fmt: skip
    converted = AutowareMessages().convert("tracks", "v", "s", payload)
    assert converted is not None and converted[0] == TRACKED
    bag = Ros2Bag(tmp_path / "v1.ros2.mcap", "fleet", AutowareMessages())
    bag.add("tracks", "v", "s", payload, log_time=1, publish_time=stamp(0), sequence=0)
    bag.close()
    (message,) = read_bag(bag.path)
    assert check_tracked(message.msg, payload, "v", "s", "kitti") == 3
