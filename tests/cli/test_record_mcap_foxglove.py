"""What Foxglove gets from ``record --format mcap``: a JSON twin of every raw channel (the
message with its box table as one object of numbers per box, for the Plot panel) under a schema
Foxglove's JSON Schema reader takes, SceneUpdate boxes of every published track and detection,
and the detection pose as a FrameTransform; and ``replay mcap`` still sends only the raw
detections. The same run's ``--ros2`` bag is read back with rosbags
(tests/cli/test_record_mcap_ros2.py has the checks)."""

from __future__ import annotations

import dataclasses
import json
import math
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import msgpack
import numpy as np
import pytest
import zenoh
from mcap.reader import make_reader

from simpletrack.cli.replay_mcap import load
from simpletrack.mcap.foxglove import FoxgloveChannels, flatten, foxglove_schema
from simpletrack.session import open_session
from simpletrack.wire import Rejection, decode_track_frame, encode_detection_frame
from tests.cli.test_record_mcap import kill_leftovers, read, record, service
from tests.mcap.ros2_checks import DETECTED, TRACKED, check_detected, check_tracked, read_bag
from tests.mcap.twins import check_twin
from tests.service_helpers import ROOT, Client, free_port, moving_cars, stamp, wait_for

FRAMES = 6
VENDORED = ROOT / "clients" / "simpletrack" / "mcap" / "foxglove_schemas"
YAW = 0.5
TRANSLATION = (100.0, 50.0, 2.0)


def pose() -> np.ndarray:
    p = np.eye(4)
    p[:2, :2] = [[math.cos(YAW), -math.sin(YAW)], [math.sin(YAW), math.cos(YAW)]]
    p[:3, 3] = TRANSLATION
    return p


def cars(k: int) -> Any:
    # Two cars, one driving along +x at 10 m/s, one standing (no velocity arrow).
    boxes = moving_cars(k, 2)
    return dataclasses.replace(boxes, velocity=np.float32([[10.0, 0.0], [0.0, 0.0]]))


@pytest.fixture(scope="module")
def recorded(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Path]:
    """FRAMES detection frames with a pose sent to a real service, recorded with the tracks."""
    tmp = tmp_path_factory.mktemp("foxglove")
    svc = service(tmp, "fox")
    planner = Client(svc.endpoint)
    out = tmp / "fox.mcap"
    listen = f"tcp/127.0.0.1:{free_port()}"
    try:
        rec = record(
            "--format", "mcap", "--out", str(out), "--connect", svc.endpoint, "--listen", listen,
            "--what", "detections,tracks", "--frames", str(2 * FRAMES), "--ros2",
        )  # fmt: skip
        # Zenoh peers route nobody else's samples: the vehicle reaches the recorder directly.
        with open_session(mode="peer", connect=[svc.endpoint, listen]) as vehicle:
            pub = vehicle.declare_publisher(
                "fleet/veh/lidar/detections", congestion_control=zenoh.CongestionControl.BLOCK
            )
            wait_for(lambda: pub.matching_status.matching, 10, "the detections' subscribers")
            for k in range(FRAMES):
                pub.put(
                    encode_detection_frame(
                        vehicle="veh", sensor="lidar", seq=k, stamp_ns=stamp(k),
                        frame_id="lidar", boxes=cars(k), pose=pose(),
                    )
                )  # fmt: skip
            wait_for(lambda: planner.received.n_tracks("veh/lidar") == FRAMES, 30, "tracks")
            code, stdout, err = rec.wait()
        assert code == 0, err
        assert f"{2 * FRAMES} messages" in stdout, stdout
        assert f"{2 * FRAMES} ROS 2 messages to {tmp / 'fox.ros2.mcap'}" in stdout, stdout
    finally:
        kill_leftovers()
        planner.close()
        svc.stop()
    yield out


def by_topic(messages: list[tuple[Any, Any, Any]]) -> dict[str, list[Any]]:
    out: dict[str, list[Any]] = {}
    for _, channel, message in messages:
        out.setdefault(channel.topic, []).append(message)
    return out


def validate(value: Any, schema: dict[str, Any], path: str = "$") -> None:
    """The JSON Schema subset Foxglove's own schemas use, strictly: type, properties (no key
    outside them), required, items, minimum/maximum, oneOf of consts."""
    if "oneOf" in schema:
        assert value in [alt["const"] for alt in schema["oneOf"]], (path, value)
        return
    kind = schema["type"]
    if kind == "object":
        assert isinstance(value, dict), (path, value)
        props = schema.get("properties", {})
        assert set(value) <= set(props), (path, set(value) - set(props))
        assert set(schema.get("required", [])) <= set(value), (path, schema["required"])
        for k, v in value.items():
            validate(v, props[k], f"{path}.{k}")
    elif kind == "array":
        assert isinstance(value, list), (path, value)
        for i, v in enumerate(value):
            validate(v, schema["items"], f"{path}[{i}]")
    else:
        want = {"string": str, "boolean": bool, "integer": int, "number": (int, float)}[kind]
        assert isinstance(value, want) and (kind == "boolean" or type(value) is not bool), path
        assert value >= schema.get("minimum", value) and value <= schema.get("maximum", value)


def foxglove_reads(schema: dict[str, Any], path: str = "$") -> list[str]:
    """What Foxglove's JSON Schema reader (packages/mcap-support parseJsonSchema.ts) rejects:
    an object without properties, a property without one supported type, base64 in arrays."""
    if schema.get("type") != "object":
        return [f"{path}: not an object"]
    problems = []
    for name, field in schema.get("properties", {}).items():
        where = f"{path}.{name}"
        if isinstance(field.get("oneOf"), list):
            if not all(isinstance(a.get("const"), int) for a in field["oneOf"]):
                problems.append(f"{where}: oneOf of non-numbers")
            continue
        kind = field.get("type")
        if kind == "object":
            problems += foxglove_reads(field, where)
        elif kind == "array":
            item = field.get("items", {})
            if item.get("type") == "object":
                problems += foxglove_reads(item, where)
            elif item.get("type") not in ("boolean", "string", "number", "integer"):
                problems.append(f"{where}[]: type {item.get('type')!r}")
            elif "contentEncoding" in item:
                problems.append(f"{where}[]: contentEncoding in an array")
        elif kind not in ("boolean", "string", "number", "integer"):
            problems.append(f"{where}: type {kind!r}")
        elif field.get("contentEncoding", "base64") != "base64":
            problems.append(f"{where}: contentEncoding {field['contentEncoding']}")
    return problems


def test_json_twins_hold_the_messages_as_plottable_rows(recorded: Path) -> None:
    (summary, metadata), messages = read(recorded)
    assert metadata["simpletrack"]["foxglove"] == "true"
    assert metadata["simpletrack"]["ros2"] == "fox.ros2.mcap"
    topics = by_topic(messages)
    raw_keys = {c.topic for c in summary.channels.values() if c.message_encoding == "msgpack"}
    assert raw_keys == {"fleet/veh/lidar/detections", "fleet/veh/lidar/tracks"}
    channels = {c.topic: c for c in summary.channels.values()}
    for key, table in (
        ("fleet/veh/lidar/detections", "boxes"),
        ("fleet/veh/lidar/tracks", "tracks"),
    ):
        twin = channels[f"{key}/json"]
        assert twin.message_encoding == "json"
        schema = summary.schemas[twin.schema_id]
        assert schema.encoding == "jsonschema"
        assert schema.name == summary.schemas[channels[key].schema_id].name
        fields = json.loads(schema.data)["properties"][table]["items"]["properties"]
        assert len(topics[f"{key}/json"]) == len(topics[key]) == FRAMES
        for raw, js in zip(topics[key], topics[f"{key}/json"], strict=True):
            value = json.loads(js.data)
            check_twin(value, raw.data, schema.name)
            assert all(set(row) <= set(fields) for row in value[table])
            assert (js.log_time, js.publish_time, js.sequence) == (
                raw.log_time,
                raw.publish_time,
                raw.sequence,
            )
    # What the README's Plot path picks: fleet/veh/lidar/tracks/json.tracks[:]{id==0}.x, one
    # number per message, the car driving along +x at 10 m/s in the world frame (the pose).
    xs = [
        [t["x"] for t in json.loads(m.data)["tracks"] if t["id"] == 0]
        for m in topics["fleet/veh/lidar/tracks/json"]
    ]
    assert all(len(x) == 1 for x in xs)
    steps = np.diff([x[0] for x in xs])
    assert np.allclose(steps, math.cos(YAW), atol=0.05), steps  # 1 m a frame, turned by YAW


def test_json_schemas_are_ones_foxglove_reads() -> None:
    for name, table in (
        ("DetectionFrame", "boxes"),
        ("TrackFrame", "tracks"),
        ("FrameError", None),
    ):
        wire = json.loads((ROOT / "schemas" / "json" / f"{name}.schema.json").read_bytes())
        assert foxglove_reads(wire), name  # $ref and anyOf-with-null: Foxglove gives up
        flat = json.loads(foxglove_schema(name))
        assert foxglove_reads(flat) == [], name
        assert "$ref" not in json.dumps(flat)
        plain = flatten(wire)
        if table is None:
            assert flat == plain
            continue
        # Nothing lost but the null alternative: every other field is the wire's; the table is
        # an array of rows with a field for each column's values.
        assert set(flat["properties"]) == set(wire["properties"]) | {"count", "classes"}
        others = [k for k in plain["properties"] if k != table]
        assert {k: flat["properties"][k] for k in others} == {
            k: plain["properties"][k] for k in others
        }
        rows = flat["properties"][table]
        assert rows["type"] == "array" and rows["items"]["type"] == "object"
        fields = rows["items"]["properties"]
        for field in ("class", "class_index", "x", "y", "z", "length", "width", "height", "yaw"):
            assert field in fields, (name, field)
        assert fields["x"]["type"] == "number" and fields["class"]["type"] == "string"
        assert not any("contentEncoding" in json.dumps(f) for f in fields.values())
    fields = json.loads(foxglove_schema("TrackFrame"))["properties"]["tracks"]["items"]
    assert fields["properties"]["id"]["type"] == "integer"
    assert fields["properties"]["covariance"] == {
        "type": "array",
        "items": {"type": "number"},
        "description": fields["properties"]["covariance"]["description"],
    }
    for field in ("vx", "vy", "vz", "speed", "score", "state", "state_name", "age_s"):
        assert field in fields["properties"], field
    for name in ("foxglove.SceneUpdate", "foxglove.FrameTransform"):
        assert foxglove_reads(json.loads(foxglove_schema(name))) == [], name


def test_scene_updates_draw_every_published_track(recorded: Path) -> None:
    (summary, _), messages = read(recorded)
    topics = by_topic(messages)
    vendored = (VENDORED / "SceneUpdate.json").read_bytes()
    scene_schema = json.loads(vendored)
    channels = {c.topic: c for c in summary.channels.values()}
    for leaf in ("detections", "tracks"):
        channel = channels[f"fleet/veh/lidar/{leaf}/scene"]
        assert channel.message_encoding == "json"
        schema = summary.schemas[channel.schema_id]
        assert (schema.name, schema.encoding, schema.data) == (
            "foxglove.SceneUpdate",
            "jsonschema",
            vendored,
        )
    tracks = topics["fleet/veh/lidar/tracks"]
    scenes = topics["fleet/veh/lidar/tracks/scene"]
    assert len(scenes) == len(tracks) == FRAMES
    confirmed = 0
    for raw, message in zip(tracks, scenes, strict=True):
        scene = json.loads(message.data)
        validate(scene, scene_schema)
        decoded = decode_track_frame(raw.data)
        assert not isinstance(decoded, Rejection), decoded
        frame, arrays = decoded
        assert frame.frame_id == "world"  # the pose put the tracks in the world frame
        sec, nsec = divmod(frame.stamp_ns, 10**9)
        assert scene["deletions"] == [
            {"timestamp": {"sec": sec, "nsec": nsec}, "type": 1, "id": ""}
        ]
        entities = {e["id"]: e for e in scene["entities"]}
        assert sorted(entities) == sorted(f"veh/lidar/{i}" for i in arrays.id.tolist())
        for i in range(len(arrays)):
            entity = entities[f"veh/lidar/{arrays.id[i]}"]
            assert entity["frame_id"] == "world"
            assert entity["timestamp"] == {"sec": sec, "nsec": nsec}
            (cube,) = entity["cubes"]
            position = cube["pose"]["position"]
            assert [position[a] for a in "xyz"] == arrays.center[i].tolist()
            assert [cube["size"][a] for a in "xyz"] == arrays.size[i].tolist()
            q = cube["pose"]["orientation"]
            assert math.isclose(2 * math.atan2(q["z"], q["w"]), float(arrays.yaw[i]), abs_tol=1e-6)
            assert entity["texts"][0]["text"].startswith(f"{arrays.id[i]} Car")
            speed = float(np.linalg.norm(arrays.velocity[i]))
            assert len(entity["arrows"]) == (1 if speed >= 0.1 else 0)
            if entity["arrows"]:
                assert math.isclose(entity["arrows"][0]["shaft_length"], speed, rel_tol=1e-6)
            confirmed += int(arrays.state[i]) == 1
    assert confirmed > 0  # some boxes are of confirmed tracks, not only tentative ones

    for message in topics["fleet/veh/lidar/detections/scene"]:
        scene = json.loads(message.data)
        validate(scene, scene_schema)
        assert [e["id"] for e in scene["entities"]] == ["veh/lidar/d0", "veh/lidar/d1"]
        assert {e["frame_id"] for e in scene["entities"]} == {"lidar"}
        assert [len(e["arrows"]) for e in scene["entities"]] == [1, 0]


def test_detection_pose_becomes_a_frame_transform(recorded: Path) -> None:
    _, messages = read(recorded)
    transforms = by_topic(messages)["fleet/veh/lidar/detections/tf"]
    schema = json.loads((VENDORED / "FrameTransform.json").read_bytes())
    assert len(transforms) == FRAMES
    for k, message in enumerate(transforms):
        tf = json.loads(message.data)
        validate(tf, schema)
        assert (tf["parent_frame_id"], tf["child_frame_id"]) == ("world", "lidar")
        assert tf["timestamp"] == dict(zip(("sec", "nsec"), divmod(stamp(k), 10**9), strict=True))
        assert [tf["translation"][a] for a in "xyz"] == list(TRANSLATION)
        q = tf["rotation"]
        assert [q["x"], q["y"]] == [0.0, 0.0]
        assert math.isclose(2 * math.atan2(q["z"], q["w"]), YAW, abs_tol=1e-12)


def test_replay_mcap_takes_only_the_raw_detections(recorded: Path) -> None:
    _, messages = read(recorded)
    raw = [m.data for _, c, m in messages if c.topic == "fleet/veh/lidar/detections"]
    loaded = load(recorded, None)
    assert [r.payload for r in loaded] == raw and len(raw) == FRAMES
    assert {(r.prefix, r.vehicle, r.sensor) for r in loaded} == {("fleet", "veh", "lidar")}


def test_damaged_payloads_add_no_broken_twins() -> None:
    channels = FoxgloveChannels()
    key = "fleet/veh/lidar/detections"
    assert channels.derive(key, "detections", "veh", "lidar", b"\xc1 not msgpack") == []
    good = encode_detection_frame(
        vehicle="veh", sensor="lidar", seq=0, stamp_ns=5, frame_id="lidar", boxes=cars(0)
    )
    frame = msgpack.unpackb(good)
    frame["boxes"]["count"] = 3  # columns hold 2 rows: no rows to show, nothing to draw
    assert channels.derive(key, "detections", "veh", "lidar", msgpack.packb(frame)) == []
    frame["boxes"]["count"] = 2
    frame["pose"] = [math.nan] * 16
    derived = channels.derive(key, "detections", "veh", "lidar", msgpack.packb(frame))
    assert [d.topic for d in derived] == [f"{key}/json", f"{key}/scene"]  # no transform of NaN
    assert json.loads(derived[0].data)["pose"] == [None] * 16  # JSON has no NaN
    center = np.frombuffer(frame["boxes"]["center"], "<f4").copy()
    center[0] = math.nan
    frame["boxes"]["center"] = center.tobytes()
    derived = channels.derive(key, "detections", "veh", "lidar", msgpack.packb(frame))
    assert json.loads(derived[0].data)["boxes"][0]["x"] is None  # a NaN box: null, still a row


def test_the_ros2_bag_holds_every_frame_as_autoware_messages(recorded: Path) -> None:
    """``--ros2`` of a real service's run, read by rosbags: every TrackedObjects decodes and
    matches the msgpack channel's tracks (the documented uuid, positions within 1e-6), every
    DetectedObjects the detections; labels by the service's preset (kitti)."""
    bag = recorded.with_name("fox.ros2.mcap")
    with open(bag, "rb") as f:
        assert make_reader(f).get_header().profile == "ros2"
    raw = by_topic(read(recorded)[1])
    got = read_bag(bag)
    topics = {
        "/simpletrack/veh/lidar/detected_objects": "fleet/veh/lidar/detections",
        "/simpletrack/veh/lidar/tracked_objects": "fleet/veh/lidar/tracks",
    }
    assert {m.topic for m in got} == set(topics)
    objects = 0
    for topic, key in topics.items():
        mine = [m for m in got if m.topic == topic]
        assert len(mine) == len(raw[key]) == FRAMES
        for message, recorded_message in zip(mine, raw[key], strict=True):
            assert message.log_time == recorded_message.log_time
            if key.endswith("/tracks"):
                assert message.msgtype == TRACKED
                objects += check_tracked(
                    message.msg, recorded_message.data, "veh", "lidar", "kitti"
                )
            else:
                assert message.msgtype == DETECTED
                assert check_detected(message.msg, recorded_message.data, "kitti") == 2
    assert objects > FRAMES  # the two cars were tracked
