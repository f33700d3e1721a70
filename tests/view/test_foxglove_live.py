"""``simpletrack view --foxglove``: a Foxglove WebSocket client on a real Zenoh session on
127.0.0.1 subscribes to the advertised channels and gets a SceneUpdate per track frame, one
entity per track (the recorder's scenes), and a FrameTransform per detection frame.

Skipped without foxglove-sdk (the ``foxglove`` extra), except under CI=true, which installs it.
"""

from __future__ import annotations

import contextlib
import json
import os
import signal
import socket
import struct
import subprocess
import sys
import time
from collections.abc import Iterator
from dataclasses import dataclass, field
from typing import Any

import pytest
import zenoh

from simpletrack.session import open_session
from simpletrack.spawn import free_port
from simpletrack.view import FoxgloveLive, serve_foxglove
from simpletrack.view import foxglove_live as live_mod
from simpletrack.wire.track_ids import global_id
from tests.service_helpers import ROOT
from tests.view.frames import (
    Known,
    Sender,
    VehicleSender,
    detection_frame,
    pose_at,
    vehicle_arrays,
)

pytestmark = pytest.mark.zenoh

# foxglove-sdk's server speaks foxglove.sdk.v1, the Foxglove WebSocket protocol v1 under its
# current name; the Foxglove app offers both names, as this client does.
SUBPROTOCOLS = ["foxglove.sdk.v1", "foxglove.websocket.v1"]
MESSAGE_DATA = 0x01  # the protocol's binary opcode: subscription id u32, log time u64, payload


def need_foxglove() -> None:
    if live_mod.foxglove_available():
        return
    message = f"foxglove-sdk is not installed (pip install '{live_mod.FOXGLOVE_EXTRA}')"
    if os.environ.get("CI") == "true":
        pytest.fail(message)  # CI installs the extra: these must run there
    pytest.skip(message)


@dataclass
class Client:
    """A minimal Foxglove WebSocket client: channels by topic, messages by subscription."""

    ws: Any
    server_info: dict[str, Any] = field(default_factory=dict)
    channels: dict[str, dict[str, Any]] = field(default_factory=dict)
    messages: dict[int, list[bytes]] = field(default_factory=dict)
    subs: dict[str, int] = field(default_factory=dict)

    @classmethod
    @contextlib.contextmanager
    def connect(cls, url: str) -> Iterator[Client]:
        from websockets.sync.client import connect

        with connect(url, subprotocols=SUBPROTOCOLS, open_timeout=5) as ws:  # type: ignore[arg-type]
            client = cls(ws)
            assert ws.subprotocol in SUBPROTOCOLS
            client.pump_until(lambda: bool(client.server_info), 5, "serverInfo")
            yield client

    def pump(self, timeout: float) -> None:
        """Read what comes within ``timeout`` seconds (at least one message if one comes)."""
        deadline = time.monotonic() + timeout
        while True:
            left = deadline - time.monotonic()
            try:
                msg = self.ws.recv(timeout=max(left, 0.0))
            except TimeoutError:
                return
            if isinstance(msg, str):
                op = json.loads(msg)
                if op["op"] == "serverInfo":
                    self.server_info = op
                elif op["op"] == "advertise":
                    self.channels.update({c["topic"]: c for c in op["channels"]})
            else:
                assert msg[0] == MESSAGE_DATA, msg[:1]
                sub, _log_time = struct.unpack_from("<IQ", msg, 1)
                self.messages.setdefault(sub, []).append(msg[13:])
            if left <= 0:
                return

    def pump_until(self, pred: Any, timeout: float, what: str) -> None:
        deadline = time.monotonic() + timeout
        while not pred():
            assert time.monotonic() < deadline, f"timed out waiting for {what}"
            self.pump(0.05)

    def subscribe(self, topic: str) -> int:
        sub = len(self.subs) + 1
        self.subs[topic] = sub
        channel = self.channels[topic]["id"]
        self.ws.send(
            json.dumps({"op": "subscribe", "subscriptions": [{"id": sub, "channelId": channel}]})
        )
        return sub

    def take(self, topic: str) -> list[dict[str, Any]]:
        """The decoded messages on ``topic`` so far, forgotten once taken."""
        out = self.messages.pop(self.subs[topic], [])
        return [json.loads(m) for m in out]


@dataclass
class Rig:
    live: FoxgloveLive
    publisher: zenoh.Session
    client: Client

    def advertised(self, topic: str, put: Any) -> dict[str, Any]:
        """``put()`` frames until ``topic`` is advertised (channels come with their first
        frame); its channel."""
        deadline = time.monotonic() + 10
        while topic not in self.client.channels:
            assert time.monotonic() < deadline, (topic, sorted(self.client.channels))
            put()
            self.client.pump(0.2)
        return self.client.channels[topic]

    def subscribed(self, topics: list[str], put: Any) -> None:
        """Subscribe to ``topics`` and ``put()`` frames until each has delivered (the
        server takes a subscription in its own time); then forget what came."""
        for topic in topics:
            self.client.subscribe(topic)
        deadline = time.monotonic() + 10
        while not all(self.client.messages.get(self.client.subs[t]) for t in topics):
            assert time.monotonic() < deadline, f"nothing came on {topics}"
            put()
            self.client.pump(0.2)
        for topic in topics:
            self.client.take(topic)


@pytest.fixture
def rig() -> Iterator[Rig]:
    need_foxglove()
    from simpletrack.mcap.foxglove import foxglove_schema
    from simpletrack.mcap.scene import SceneConverter

    endpoint = f"tcp/127.0.0.1:{free_port()}"
    view_session = open_session(mode="peer", listen=[endpoint])
    publisher = open_session(mode="peer", connect=[endpoint])
    live = None
    try:
        live = serve_foxglove(
            view_session,
            "fleet",
            "127.0.0.1",
            0,
            scenes=SceneConverter(),
            schema=foxglove_schema,
            detections=True,
        )
        with Client.connect(live.url) as client:
            yield Rig(live, publisher, client)
    finally:
        if live is not None:
            live.close()
        publisher.close()  # type: ignore[no-untyped-call]
        view_session.close()  # type: ignore[no-untyped-call]


def stamp_of(scene: dict[str, Any]) -> int:
    t = scene["deletions"][0]["timestamp"]
    return int(t["sec"]) * 1_000_000_000 + int(t["nsec"])


def test_each_track_frame_is_a_scene_update_with_one_entity_per_track(rig: Rig) -> None:
    sender = Sender(rig.publisher, "veh01", "lidar")
    sender.wait_matched(detections=True)
    pose = pose_at(5.0, 0.0, 0.0)
    one = [Known(1, 10.0, 2.0, 4.0, 1.8, 0.3, 1)]
    topic = "fleet/veh01/lidar/tracks/scene"
    channel = rig.advertised(topic, lambda: sender.tracks(one, pose))
    assert channel["encoding"] == "json"
    assert channel["schemaName"] == "foxglove.SceneUpdate"
    assert channel["schemaEncoding"] == "jsonschema"
    assert json.loads(channel["schema"])["title"] == "foxglove.SceneUpdate"
    rig.subscribed([topic], lambda: sender.tracks(one, pose))

    frames = [
        [Known(1, 10.0, 2.0, 4.0, 1.8, 0.3, 1, vx=5.0)],
        [Known(1, 10.5, 2.0, 4.0, 1.8, 0.3, 1), Known(2, -4.0, 7.0, 0.8, 0.6, 1.2, 0, cls=1)],
        [Known(i, float(i), -float(i), 4.0, 1.8, 0.0, i % 3) for i in range(3, 8)],
    ]
    stamps = [1_700_000_000_000_000_000 + k * 100_000_000 for k in range(len(frames))]
    for tracks, stamp in zip(frames, stamps, strict=True):
        sender.tracks(tracks, pose, stamp_ns=stamp)
    got: list[dict[str, Any]] = []

    def counted() -> bool:
        got.extend(s for s in rig.client.take(topic) if stamp_of(s) in stamps)
        return len(got) >= len(frames)

    rig.client.pump_until(counted, 10, "the frames' scenes")
    assert [stamp_of(s) for s in got] == stamps  # one per frame, in order
    for scene, tracks in zip(got, frames, strict=True):
        assert scene["deletions"][0]["type"] == 1  # ALL before this stamp: only this frame
        entities = scene["entities"]
        assert [e["id"] for e in entities] == [global_id("veh01", "lidar", t.id) for t in tracks]
        for entity, t in zip(entities, tracks, strict=True):
            assert entity["frame_id"] == "world"
            (cube,) = entity["cubes"]
            assert cube["pose"]["position"]["x"] == pytest.approx(t.x, abs=1e-4)
            assert cube["pose"]["position"]["y"] == pytest.approx(t.y, abs=1e-4)
            assert cube["size"]["x"] == pytest.approx(t.l, abs=1e-4)
            assert len(entity["arrows"]) == (1 if t.vx else 0)
    assert rig.live.dropped == 0
    sender.undeclare()


def test_a_fused_vehicle_and_its_sensors_detections_with_their_transforms(rig: Rig) -> None:
    sensors = ["lidar", "camera"]
    vehicle = VehicleSender(rig.publisher, "veh02", sensors)
    vehicle.wait_matched()
    tracks = [Known(4, 12.0, 1.0, 4.0, 1.8, 0.0, 1), Known(9, 20.0, -3.0, 4.0, 1.8, 0.5, 1)]
    columns = vehicle_arrays(tracks, [0.93, 0.6], [[100, -1], [100, 100]])
    extrinsic = pose_at(1.5, 0.0, 0.0, z=1.2)  # camera -> vehicle
    stamp = [2_000_000_000]

    def put() -> None:
        stamp[0] += 100_000_000
        vehicle.tracks("camera", columns, ["ok", "ok"], stamp[0])
        dets = detection_frame("veh02", "camera", 1, tracks, extrinsic=extrinsic)
        vehicle.detections("camera", dets)

    scene_topic = "fleet/veh02/@vehicle/tracks/scene"
    dets_topic = "fleet/veh02/camera/detections/scene"
    tf_topic = "fleet/veh02/camera/detections/tf"
    for topic in (scene_topic, dets_topic, tf_topic):
        rig.advertised(topic, put)
    assert rig.client.channels[tf_topic]["schemaName"] == "foxglove.FrameTransform"
    rig.subscribed([scene_topic, dets_topic, tf_topic], put)
    put()
    rig.client.pump_until(
        lambda: all(rig.client.messages.get(rig.client.subs[t]) for t in (scene_topic, tf_topic)),
        10,
        "a fused scene and a transform",
    )
    scene = rig.client.take(scene_topic)[-1]
    assert [e["id"] for e in scene["entities"]] == ["veh02/@vehicle/4", "veh02/@vehicle/9"]
    assert all(e["frame_id"] == "base_link" for e in scene["entities"])
    sensors_of = [
        {m["key"]: m["value"] for m in e["metadata"]}["sensors"] for e in scene["entities"]
    ]
    assert sensors_of == ["lidar", "lidar,camera"]
    tf = rig.client.take(tf_topic)[-1]
    assert (tf["parent_frame_id"], tf["child_frame_id"]) == ("base_link", "camera")
    assert tf["translation"] == pytest.approx({"x": 1.5, "y": 0.0, "z": 1.2})
    vehicle.undeclare()


def test_live_topics_are_the_recordings() -> None:
    """A Foxglove layout made on a recording (record --format mcap) works live."""
    from simpletrack.mcap import foxglove

    assert (live_mod.SCENE_SUFFIX, live_mod.TF_SUFFIX) == (
        foxglove.SCENE_SUFFIX,
        foxglove.TF_SUFFIX,
    )
    assert (live_mod.SCENE_SCHEMA, live_mod.TF_SCHEMA) == (
        foxglove.SCENE_SCHEMA,
        foxglove.TF_SCHEMA,
    )


def view_cmd(*args: str, python: list[str] | None = None) -> list[str]:
    listen = f"tcp/127.0.0.1:{free_port()}"
    head = python or [sys.executable, "-m", "simpletrack.cli.main"]
    return [*head, "view", "--listen", listen, *args]


def test_without_the_extra_the_command_names_it_in_one_line() -> None:
    # foxglove-sdk made unimportable: what a light install without the extra sees.
    code = (
        "import sys; sys.modules['foxglove'] = None; "
        "from simpletrack.cli.main import main; sys.exit(main(sys.argv[1:]))"
    )
    done = subprocess.run(
        view_cmd("--http-port", "0", "--foxglove", python=[sys.executable, "-c", code]),
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert done.returncode == 2, done.stderr
    assert done.stderr.strip().splitlines() == [
        "simpletrack view: error: --foxglove: foxglove-sdk is not installed: "
        f"pip install '{live_mod.FOXGLOVE_EXTRA}'"
    ]


def test_the_command_prints_the_foxglove_url_and_serves_it() -> None:
    need_foxglove()
    port = free_port()
    proc = subprocess.Popen(
        view_cmd("--http-port", "0", "--foxglove", str(port)),
        cwd=ROOT,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    try:
        assert proc.stdout is not None
        assert proc.stdout.readline().startswith("view: http://127.0.0.1:")
        line = proc.stdout.readline()
        assert line.startswith(f"foxglove: ws://127.0.0.1:{port} "), line
        with Client.connect(f"ws://127.0.0.1:{port}") as client:
            assert client.server_info["name"] == "simpletrack view"
    finally:
        proc.send_signal(signal.SIGTERM)
        assert proc.wait(30) == 0


def test_a_taken_foxglove_port_is_a_one_line_error_naming_it() -> None:
    need_foxglove()
    with socket.socket() as taken:
        taken.bind(("127.0.0.1", 0))
        taken.listen()
        port = taken.getsockname()[1]
        done = subprocess.run(
            view_cmd("--http-port", "0", "--foxglove", str(port)),
            cwd=ROOT,
            capture_output=True,
            text=True,
            timeout=60,
        )
    assert done.returncode == 2, done.stderr
    assert done.stderr.strip().splitlines() == [
        f"simpletrack view: error: --foxglove {port} is already in use on 127.0.0.1"
    ]
