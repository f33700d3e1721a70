"""A real ``simpletrack serve --preset kitti``, a real ``simpletrack bridge ros2`` process, and
a Zenoh session playing the ROS 2 side with CDR made by rosbags: DetectedObjects in, the
tracks back as TrackedObjects, read with rosbags.

Topology: the bridge listens on its own endpoint and connects to the service; the test's
session connects to the bridge (peers do not route for each other)."""

from __future__ import annotations

import math
import subprocess
import sys
import threading
import time
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import zenoh

from simpletrack.ros2.layout import Layout, parse_attachment, topic_keys
from simpletrack.session import open_session
from simpletrack.spawn import free_port
from simpletrack.wire import FrameError, Rejection, decode_message
from tests.ros2 import rosmsgs as R
from tests.ros2.bridge_process import Bridge, start_bridge
from tests.service_helpers import ROOT, ServiceProcess, start_service, wait_for

pytestmark = pytest.mark.zenoh

T0_S = 1_700_000_000
FRAMES = 20


@pytest.fixture(scope="module")
def service(tmp_path_factory: pytest.TempPathFactory) -> Iterator[ServiceProcess]:
    svc = start_service(tmp_path_factory.mktemp("svc"), "--preset", "kitti")
    yield svc
    svc.stop()


@pytest.fixture
def bridges(tmp_path: Path) -> Iterator[list[Bridge]]:
    started: list[Bridge] = []
    yield started
    for b in started:
        b.kill()


@dataclass
class RosSide:
    """What a ROS 2 graph would see through zenoh-bridge-ros2dds or rmw_zenoh."""

    session: zenoh.Session
    publisher: zenoh.Publisher
    tracked: list[tuple[Any, bytes | None]] = field(default_factory=list)
    errors: list[FrameError] = field(default_factory=list)
    lock: threading.Lock = field(default_factory=threading.Lock)

    def n(self) -> int:
        with self.lock:
            return len(self.tracked)


@pytest.fixture
def ros_sides() -> Iterator[list[zenoh.Session]]:
    sessions: list[zenoh.Session] = []
    yield sessions
    for s in sessions:
        s.close()  # type: ignore[no-untyped-call]


def ros_side(
    sessions: list[zenoh.Session], bridge: Bridge, in_key: str, out_key: str, vehicle: str
) -> RosSide:
    session = open_session(mode="peer", connect=[bridge.endpoint])
    sessions.append(session)
    pub = session.declare_publisher(in_key, congestion_control=zenoh.CongestionControl.BLOCK)
    side = RosSide(session, pub)

    def on_tracked(sample: zenoh.Sample) -> None:
        extra = sample.attachment.to_bytes() if sample.attachment is not None else None
        with side.lock:
            side.tracked.append((R.deserialize(sample.payload.to_bytes(), R.TRACKED), extra))

    def on_error(sample: zenoh.Sample) -> None:
        err = decode_message(sample.payload.to_bytes(), FrameError)
        assert not isinstance(err, Rejection), err
        with side.lock:
            side.errors.append(err)

    session.declare_subscriber(out_key, on_tracked)
    session.declare_subscriber(f"fleet/{vehicle}/*/errors", on_error)
    wait_for(lambda: pub.matching_status.matching, 20, f"the bridge's subscriber on {in_key}")
    return side


def car(k: int) -> bytes:
    """Frame k of a car driving along +x at 10 m/s, 10 Hz, heading 0.3 rad off the x axis."""
    yaw = 0.3
    b = R.FixtureBox("Car", 1, 10.0 + k * math.cos(yaw), 2.0 + k * math.sin(yaw), 0.8,
                     4.5, 1.9, 1.6, yaw, 0.9, 10 * math.cos(yaw), 10 * math.sin(yaw))  # fmt: skip
    sec, nanosec = divmod(k * 100_000_000, 10**9)
    return R.serialize(R.detected_objects([R.detected_object(b)], T0_S + sec, nanosec))


def expected_tracks(payloads: list[bytes]) -> list[np.ndarray[Any, np.dtype[np.float32]]]:
    """The core tracker on the frames the service receives: the centres it gives."""
    from simpletrack.core.config import preset
    from simpletrack.core.frames import Frame
    from simpletrack.core.tracker import Tracker
    from simpletrack.ros2.codec import decode_detected_objects
    from simpletrack.ros2.convert import detections_to_boxes
    from simpletrack.ros2.labels import label_map
    from simpletrack.wire.convert import boxes_from_wire, tracks_to_wire

    config = preset("kitti")
    tracker = Tracker(config)
    out = []
    for k, raw in enumerate(payloads):
        arrays = detections_to_boxes(
            decode_detected_objects(raw), label_map("kitti"), config.class_names
        ).boxes
        tracks = tracker.step(Frame(boxes_from_wire(arrays), k * 0.1))
        out.append(tracks_to_wire(tracks, 0, config.class_names).center)
    return out


def run_car(side: RosSide, first: int, n: int) -> list[bytes]:
    sent, before = [], side.n()
    for i, k in enumerate(range(first, first + n)):
        sent.append(car(k))
        side.publisher.put(sent[-1])
        wait_for(lambda i=i: side.n() == before + i + 1, 20, f"TrackedObjects of frame {k}")
    return sent


def test_a_moving_car_comes_back_as_tracked_objects_with_one_stable_uuid(
    service: ServiceProcess, bridges: list[Bridge], ros_sides: list[zenoh.Session], tmp_path: Path
) -> None:
    bridge = start_bridge(bridges, tmp_path, service, "--vehicle", "veh-e2e", "--sensor", "lidar")
    keys = topic_keys(Layout.ROS2DDS)
    assert "labels kitti: CAR=Car, BICYCLE=Cyclist, PEDESTRIAN=Pedestrian" in bridge.stderr()
    side = ros_side(ros_sides, bridge, keys.in_key, keys.out_key, "veh-e2e")
    sent = run_car(side, 0, FRAMES)

    got = [msg for msg, _ in side.tracked]
    assert len(got) == FRAMES  # one TrackedObjects per DetectedObjects
    assert [(m.header.stamp.sec, m.header.stamp.nanosec) for m in got] == [
        (T0_S + k // 10, k % 10 * 100_000_000) for k in range(FRAMES)
    ]
    assert {m.header.frame_id for m in got} == {"base_link"}
    ids = {bytes(o.object_id.uuid) for m in got for o in m.objects}
    assert len(ids) == 1, "the car keeps one UUID"
    expected = expected_tracks(sent)
    assert sum(len(e) for e in expected) >= FRAMES - 3  # the core reports the car
    for k, (m, centres) in enumerate(zip(got, expected, strict=True)):
        positions = [
            [o.kinematics.pose_with_covariance.pose.position.x,
             o.kinematics.pose_with_covariance.pose.position.y,
             o.kinematics.pose_with_covariance.pose.position.z]
            for o in m.objects
        ]  # fmt: skip
        assert len(positions) == len(centres), k
        np.testing.assert_allclose(
            np.array(positions).reshape(-1, 3), centres, atol=1e-3, err_msg=str(k)
        )
    last = got[-1].objects[0]
    assert [c.label for c in last.classification] == [1]  # CAR
    assert last.shape.type == 0
    assert last.shape.dimensions.x == pytest.approx(4.5, abs=1e-3)
    assert not side.errors
    rc, out = bridge.stop()
    assert rc == 0
    assert f"{FRAMES} DetectedObjects received, {FRAMES} frames published" in out
    assert f"{FRAMES} TrackedObjects sent" in out


def test_bad_cdr_is_counted_logged_announced_and_the_bridge_goes_on(
    service: ServiceProcess, bridges: list[Bridge], ros_sides: list[zenoh.Session], tmp_path: Path
) -> None:
    bridge = start_bridge(bridges, tmp_path, service, "--vehicle", "veh-bad", "--sensor", "lidar")
    keys = topic_keys(Layout.ROS2DDS)
    side = ros_side(ros_sides, bridge, keys.in_key, keys.out_key, "veh-bad")
    run_car(side, 0, 3)
    side.publisher.put(b"not CDR at all")
    side.publisher.put(car(3)[:-40])  # a DetectedObjects cut short
    run_car(side, 3, 3)  # the bridge keeps going: one TrackedObjects per good frame
    assert side.n() == 6
    wait_for(lambda: len(side.errors) == 2, 10, "the two refusals on the errors key")
    assert {(e.reason.value, e.instance) for e in side.errors} == {
        ("malformed", "ros2-bridge-veh-bad-lidar")
    }
    assert "frame refused on perception/object_recognition/detection/objects" in bridge.stderr()
    rc, out = bridge.stop()
    assert rc == 0
    assert "8 DetectedObjects received, 6 frames published" in out
    assert "2 refused (bad_cdr 2)" in out


def test_rmw_zenoh_keys_attachments_and_graph_tokens(
    service: ServiceProcess, bridges: list[Bridge], ros_sides: list[zenoh.Session], tmp_path: Path
) -> None:
    bridge = start_bridge(
        bridges, tmp_path, service, "--vehicle", "veh-rmw", "--layout", "rmw_zenoh", "--domain", "7"
    )
    keys = topic_keys(Layout.RMW_ZENOH, domain=7)
    assert keys.in_key.startswith("7/perception/object_recognition/detection/objects/")
    side = ros_side(ros_sides, bridge, keys.in_key, keys.out_key, "veh-rmw")
    run_car(side, 0, 3)
    attachments = [parse_attachment(a) for _, a in side.tracked if a is not None]
    assert [seq for seq, _, _ in attachments] == [1, 2, 3]
    assert len({gid for _, _, gid in attachments}) == 1
    stamps = [stamp for _, stamp, _ in attachments]
    assert stamps == sorted(stamps) and abs(stamps[-1] - time.time_ns()) < 60 * 10**9
    tokens = [
        str(r.ok.key_expr)
        for r in side.session.liveliness().get("@ros2_lv/7/**", timeout=5)
        if r.ok
    ]
    kinds = sorted(t.split("/")[5] for t in tokens)
    assert kinds == ["MP", "MS", "NN"], tokens
    [mp] = [t for t in tokens if t.split("/")[5] == "MP"]
    assert "/%perception%object_recognition%tracking%objects/" in mp
    assert mp.endswith(keys.out_key.split("/")[-1] + "/::,10:,:,:,,")
    rc, _ = bridge.stop()
    assert rc == 0


def test_without_a_service_and_labels_the_bridge_says_what_to_do(tmp_path: Path) -> None:
    port = free_port()
    proc = subprocess.run(
        [sys.executable, "-m", "simpletrack.cli.main", "bridge", "ros2", "--vehicle", "v",
         "--connect", f"tcp/127.0.0.1:{port}", "--status-timeout", "0.5"],
        cwd=ROOT, capture_output=True, text=True, timeout=60,
    )  # fmt: skip
    assert proc.returncode == 2
    assert "no service answered under 'fleet' within 0.5 s" in proc.stderr
    assert "--labels" in proc.stderr
    assert "Traceback" not in proc.stderr
