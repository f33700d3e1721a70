"""A fused vehicle's tracks (``<prefix>/<vehicle>/@vehicle/tracks``, VehicleTrackFrame) in an
MCAP recording: subscribed to with a whole vehicle or the fleet, written byte for byte under
their own schema, with a JSON twin and a SceneUpdate of global ids and existence; a fused
sensor's extrinsic becomes a FrameTransform from the vehicle's frame; ``replay mcap`` never
takes the fused tracks for detections."""

from __future__ import annotations

import dataclasses
import json
import math
from pathlib import Path
from typing import Any

import msgpack
import numpy as np
import pytest
from mcap.reader import make_reader

from simpletrack.cli.replay_mcap import load
from simpletrack.mcap.format import recorded_keys, schema_name, split_key
from simpletrack.mcap.foxglove import FoxgloveChannels, flatten, foxglove_schema
from simpletrack.mcap.writer import McapRecorder
from simpletrack.wire import TrackArrays, encode_detection_frame, encode_vehicle_track_frame
from simpletrack.wire.reasons import SensorCondition
from tests.cli.test_record_mcap_foxglove import (
    VENDORED,
    foxglove_reads,
    validate,
)
from tests.mcap.test_writer import _Payload, _Sample
from tests.mcap.twins import check_twin
from tests.service_helpers import ROOT, moving_cars, stamp

VEHICLE_KEY = "fleet/veh01/@vehicle/tracks"
SENSORS = ["lidar", "camera"]
BASE = "veh01_base"  # the fused tracks' frame (fusion.vehicle_frame_id)
LEAVES = ["detections", "tracks", "errors"]


def fused_tracks(k: int) -> TrackArrays:
    """Two fused tracks at frame k: one updated by both sensors, one by the lidar alone."""
    boxes = moving_cars(k, 2)
    return TrackArrays(
        classes=("Car",),
        id=np.array([7, 12], np.int64),
        class_index=np.zeros(2, np.int32),
        center=boxes.center,
        size=boxes.size,
        yaw=np.float32([0.1, -0.2]),
        score=np.array([0.9, 0.6]),
        velocity=np.float32([[10.0, 0.0, 0.0], [0.0, 0.0, 0.0]]),
        state=np.array([1, 0], np.int32),
        hits=np.array([k + 1, 1], np.int32),
        age=np.array([k + 1, 1], np.int32),
        time_since_update=np.zeros(2, np.int32),
        age_s=np.array([0.1 * k, 0.0]),
        time_since_update_s=np.zeros(2),
        existence=np.array([0.97, 0.5]),
        sensor_stamp_ns=np.array([[stamp(k), stamp(k) - 30_000_000], [stamp(k), -1]], np.int64),
    )


def vehicle_frame(k: int, epoch: int = 1 << 16, instance: str = "a") -> bytes:
    return encode_vehicle_track_frame(
        vehicle="veh01", seq=k, stamp_ns=stamp(k), sensor="lidar", sensor_seq=k, frame_id=BASE,
        pose=None, instance=instance, received_ns=stamp(k) + 1, published_ns=stamp(k) + 2,
        sensors=SENSORS, sensor_state=[SensorCondition.OK, SensorCondition.PROBATION],
        tracks=fused_tracks(k), epoch=epoch,
    )  # fmt: skip


def extrinsic() -> np.ndarray:
    m = np.eye(4)
    m[:2, :2] = [[0.0, -1.0], [1.0, 0.0]]  # 90 degrees about z
    m[:3, 3] = (1.5, 0.0, 1.2)
    return m


def camera_detections(k: int) -> bytes:
    return encode_detection_frame(
        vehicle="veh01", sensor="camera", seq=k, stamp_ns=stamp(k), frame_id="camera",
        boxes=moving_cars(k, 2), extrinsic=extrinsic(),
    )  # fmt: skip


def sample(key: str, payload: bytes) -> Any:
    return _Sample(key, _Payload(payload))


def test_a_whole_vehicle_or_the_fleet_brings_its_fused_tracks() -> None:
    assert recorded_keys("fleet", [("*", "*")], LEAVES) == [
        "fleet/*/*/detections",
        "fleet/*/*/tracks",
        "fleet/*/*/errors",
        "fleet/*/@vehicle/tracks",
    ]
    assert recorded_keys("fleet", [("veh01", "*")], ["tracks"]) == [
        "fleet/veh01/*/tracks",
        "fleet/veh01/@vehicle/tracks",
    ]
    # One sensor is that sensor; @vehicle alone is the fused tracks alone.
    assert recorded_keys("lab", [("veh01", "lidar")], LEAVES) == [
        f"lab/veh01/lidar/{leaf}" for leaf in LEAVES
    ]
    assert recorded_keys("fleet", [("veh01", "@vehicle")], LEAVES) == [VEHICLE_KEY]
    # The fused stream has tracks only.
    assert recorded_keys("fleet", [("veh01", "*")], ["detections", "errors"]) == [
        "fleet/veh01/*/detections",
        "fleet/veh01/*/errors",
    ]
    assert recorded_keys("fleet", [("veh01", "@vehicle")], ["detections"]) == []
    # Keys another one covers are left out: each sample is written once.
    assert recorded_keys(
        "fleet", [("veh01", "lidar"), ("*", "*"), ("veh01", "@vehicle")], ["tracks"]
    ) == ["fleet/*/*/tracks", "fleet/*/@vehicle/tracks"]


def test_the_fused_key_is_a_vehicle_track_frame() -> None:
    assert split_key(VEHICLE_KEY) == ("fleet", "veh01", "@vehicle", "tracks")
    assert split_key("a/b/veh01/@vehicle/tracks") == ("a/b", "veh01", "@vehicle", "tracks")
    assert split_key("fleet/veh01/@vehicle/detections") is None  # no such stream
    assert split_key(VEHICLE_KEY + "/json") is None
    assert schema_name("@vehicle", "tracks") == "VehicleTrackFrame"
    assert schema_name("lidar", "tracks") == "TrackFrame"


@pytest.fixture
def recorded(tmp_path: Path) -> Path:
    """A fused vehicle's tracks and a camera's posed-by-extrinsic detections, as a recorder
    gets them (a fenced holder's message among them)."""
    out = tmp_path / "fused.mcap"
    rec = McapRecorder(out, "fleet")
    for s in (
        sample(VEHICLE_KEY, vehicle_frame(0)),
        sample("fleet/veh01/camera/detections", camera_detections(0)),
        sample(VEHICLE_KEY, vehicle_frame(1)),
        sample(VEHICLE_KEY, vehicle_frame(1, epoch=2 << 16, instance="b")),  # b took over
        sample(VEHICLE_KEY, vehicle_frame(2, epoch=1 << 16)),  # a, fenced: left out
        sample(VEHICLE_KEY, vehicle_frame(2, epoch=2 << 16, instance="b")),
    ):
        rec.on_sample(s)
    rec.close()
    assert (rec.messages, rec.stale, rec.unrecorded) == (5, 1, 0)
    return out


def _read(path: Path) -> tuple[Any, dict[str, list[Any]]]:
    with open(path, "rb") as f:
        reader = make_reader(f)
        summary = reader.get_summary()
        topics: dict[str, list[Any]] = {}
        for _, channel, message in reader.iter_messages(log_time_order=True):
            topics.setdefault(channel.topic, []).append(message)
    return summary, topics


def test_fused_tracks_round_trip_byte_for_byte_under_their_schema(recorded: Path) -> None:
    summary, topics = _read(recorded)
    assert summary is not None
    want = [
        vehicle_frame(0),
        vehicle_frame(1),
        vehicle_frame(1, epoch=2 << 16, instance="b"),
        vehicle_frame(2, epoch=2 << 16, instance="b"),
    ]
    assert [m.data for m in topics[VEHICLE_KEY]] == want
    assert [(m.sequence, m.publish_time) for m in topics[VEHICLE_KEY]] == [
        (k, stamp(k)) for k in (0, 1, 1, 2)
    ]
    channels = {c.topic: c for c in summary.channels.values()}
    raw = channels[VEHICLE_KEY]
    schema = summary.schemas[raw.schema_id]
    assert (raw.message_encoding, schema.name, schema.encoding) == (
        "msgpack",
        "VehicleTrackFrame",
        "jsonschema",
    )
    assert schema.data == (ROOT / "schemas" / "json" / "VehicleTrackFrame.schema.json").read_bytes()
    assert set(channels) == {
        VEHICLE_KEY,
        f"{VEHICLE_KEY}/json",
        f"{VEHICLE_KEY}/scene",
        "fleet/veh01/camera/detections",
        "fleet/veh01/camera/detections/json",
        "fleet/veh01/camera/detections/scene",
        "fleet/veh01/camera/detections/tf",
    }
    # The JSON twin: the message with a row of numbers per fused track (existence and the
    # per-sensor stamps too), under the flattened VehicleTrackFrame schema.
    twin = channels[f"{VEHICLE_KEY}/json"]
    assert summary.schemas[twin.schema_id].name == "VehicleTrackFrame"
    flat = json.loads(summary.schemas[twin.schema_id].data)
    rows = flat["properties"]["tracks"]["items"]["properties"]
    for raw_message, js in zip(topics[VEHICLE_KEY], topics[f"{VEHICLE_KEY}/json"], strict=True):
        value = json.loads(js.data)
        check_twin(value, raw_message.data, "VehicleTrackFrame")
        assert [t["existence"] for t in value["tracks"]] == [0.97, 0.5]
        assert set(value) <= set(flat["properties"])  # (null stays allowed where it was)
        assert all(set(t) <= set(rows) for t in value["tracks"])
        assert (js.log_time, js.publish_time) == (raw_message.log_time, raw_message.publish_time)


def test_the_fused_json_schema_is_one_foxglove_reads() -> None:
    wire = json.loads((ROOT / "schemas" / "json" / "VehicleTrackFrame.schema.json").read_bytes())
    flat = json.loads(foxglove_schema("VehicleTrackFrame"))
    assert foxglove_reads(flat) == [] and "$ref" not in json.dumps(flat)
    plain = flatten(wire)
    assert {
        k: v for k, v in flat["properties"].items() if k not in ("tracks", "count", "classes")
    } == {k: v for k, v in plain["properties"].items() if k != "tracks"}
    assert set(flat["properties"]) == set(wire["properties"]) | {"count", "classes"}
    rows = flat["properties"]["tracks"]["items"]["properties"]
    assert rows["existence"] == {"type": "number", "description": rows["existence"]["description"]}
    assert rows["sensor_stamp_ns"]["type"] == "array"
    assert rows["sensor_stamp_ns"]["items"] == {"type": "integer"}


def test_fused_scenes_show_global_ids_and_existence(recorded: Path) -> None:
    _, topics = _read(recorded)
    scene_schema = json.loads((VENDORED / "SceneUpdate.json").read_bytes())
    scenes = topics[f"{VEHICLE_KEY}/scene"]
    assert len(scenes) == 4
    for message, k in zip(scenes, (0, 1, 1, 2), strict=True):
        scene = json.loads(message.data)
        validate(scene, scene_schema)
        want = fused_tracks(k)
        entities = scene["entities"]
        assert [e["id"] for e in entities] == ["veh01/@vehicle/7", "veh01/@vehicle/12"]
        assert {e["frame_id"] for e in entities} == {BASE}
        assert [e["texts"][0]["text"] for e in entities] == ["7 Car p=0.97", "12 Car p=0.50"]
        meta = [{m["key"]: m["value"] for m in e["metadata"]} for e in entities]
        assert [(m["existence"], m["sensors"], m["state"]) for m in meta] == [
            ("0.970", "lidar,camera", "confirmed"),
            ("0.500", "lidar", "tentative"),
        ]
        for e, center in zip(entities, want.center.tolist(), strict=True):
            position = e["cubes"][0]["pose"]["position"]
            assert [position[a] for a in "xyz"] == center
        assert [len(e["arrows"]) for e in entities] == [1, 0]


def test_a_fused_sensors_extrinsic_places_it_in_the_vehicles_frame(recorded: Path) -> None:
    _, topics = _read(recorded)
    (message,) = topics["fleet/veh01/camera/detections/tf"]
    tf = json.loads(message.data)
    validate(tf, json.loads((VENDORED / "FrameTransform.json").read_bytes()))
    # The vehicle's frame, as its fused tracks (recorded before) named it.
    assert (tf["parent_frame_id"], tf["child_frame_id"]) == (BASE, "camera")
    assert [tf["translation"][a] for a in "xyz"] == [1.5, 0.0, 1.2]
    q = tf["rotation"]
    assert math.isclose(2 * math.atan2(q["z"], q["w"]), math.pi / 2, abs_tol=1e-12)
    # Before any fused tracks: the service's default vehicle frame.
    derived = FoxgloveChannels().derive(
        "fleet/veh01/camera/detections", "detections", "veh01", "camera", camera_detections(0)
    )
    (first,) = [d for d in derived if d.topic.endswith("/tf")]
    assert json.loads(first.data)["parent_frame_id"] == "base_link"


def test_damaged_fused_tracks_add_no_twins() -> None:
    """A table whose columns do not fit its count and sensors has no rows to show or draw:
    only its raw channel holds it."""
    frame = msgpack.unpackb(vehicle_frame(0))
    frame["tracks"]["sensor_stamp_ns"] = frame["tracks"]["sensor_stamp_ns"][:8]  # one sensor's
    derived = FoxgloveChannels().derive(
        VEHICLE_KEY, "tracks", "veh01", "@vehicle", msgpack.packb(frame)
    )
    assert derived == []
    frame = msgpack.unpackb(vehicle_frame(0))
    frame["sensors"] = "lidar"
    derived = FoxgloveChannels().derive(
        VEHICLE_KEY, "tracks", "veh01", "@vehicle", msgpack.packb(frame)
    )
    assert derived == []


def test_replay_never_takes_fused_tracks_for_detections(recorded: Path) -> None:
    loaded = load(recorded, None)
    assert [(r.vehicle, r.sensor, r.seq, r.stamp_ns) for r in loaded] == [
        ("veh01", "camera", 0, stamp(0))
    ]
    assert loaded[0].payload == camera_detections(0)


def test_a_sensor_without_pose_or_extrinsic_gets_no_transform() -> None:
    plain = encode_detection_frame(
        vehicle="veh", sensor="lidar", seq=0, stamp_ns=5, frame_id="lidar",
        boxes=dataclasses.replace(moving_cars(0, 1)),
    )  # fmt: skip
    derived = FoxgloveChannels().derive(
        "fleet/veh/lidar/detections", "detections", "veh", "lidar", plain
    )
    assert [d.topic.rsplit("/", 1)[1] for d in derived] == ["json", "scene"]
