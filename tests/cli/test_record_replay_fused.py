"""A fused vehicle recorded and replayed (docs/SERVICE.md, "Vehicle fusion"): ``record`` of
``veh01/*`` holds the sensors' detections (with their extrinsics) and the vehicle's fused tracks
(``veh01/@vehicle/tracks``) byte for byte as they travelled; ``replay mcap`` sends the
detections (never the fused tracks) into a fresh service that fuses the vehicle, which gives
the same fused tracks message for message; a JSON lines recording carries them too.

The pure parts (which keys stand for the fused stream, the JSON line, which replayed frames
a vehicle's tracks answered) have unit tests here; the writer's in tests/mcap/test_fused.py."""

from __future__ import annotations

import json
import threading
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import zenoh

from simpletrack.cli.record import track_keys, vehicle_message_to_json
from simpletrack.cli.record_mcap import parse_sensors
from simpletrack.cli.replay_mcap import Watermarks
from simpletrack.client.subscriber import VehicleTrackMessage
from simpletrack.session import open_session
from simpletrack.wire import Rejection, decode_vehicle_track_frame
from simpletrack.wire.columns import VEHICLE_TRACK_COLUMNS
from tests.cli.test_record_mcap import kill_leftovers, read, record
from tests.cli.test_replay_record import cli, one_line_error
from tests.core.fusion_helpers import T0_NS
from tests.fusion_scenario import VEHICLE, WireFrame, expected, frames, fusion_of, write_config
from tests.mcap.test_fused import vehicle_frame
from tests.service_helpers import ServiceProcess, free_port, start_service, wait_for

FUSED = f"fleet/{VEHICLE}/@vehicle/tracks"
# The frame fields a second service gives alike (not who published it, when, or its epoch).
SAME_FIELDS = (
    "vehicle", "seq", "stamp_ns", "sensor", "sensor_seq", "frame_id", "pose", "sensors",
    "sensor_state", "schema_version",
)  # fmt: skip


# ------------------------------------------------------------------------------ units
def test_record_keys_with_a_sensor_wildcard_bring_the_fused_tracks() -> None:
    assert track_keys("fleet/*/*/tracks") == ("fleet/*/*/tracks", "fleet/*/@vehicle/tracks")
    assert track_keys("lab/x/veh01/*/tracks") == (
        "lab/x/veh01/*/tracks",
        "lab/x/veh01/@vehicle/tracks",
    )
    assert track_keys("fleet/veh01/@vehicle/tracks") == (None, "fleet/veh01/@vehicle/tracks")
    # A named sensor, or an expression that is no sensor's tracks key: as given.
    for keys in ("fleet/veh01/lidar/tracks", "fleet/**", "fleet/*/*/errors", "*/*/tracks"):
        assert track_keys(keys) == (keys, None)


def test_sensors_may_name_a_fused_vehicles_stream() -> None:
    assert parse_sensors(["veh01/*,veh02/@vehicle"]) == [("veh01", "*"), ("veh02", "@vehicle")]


def test_a_fused_json_line_holds_existence_and_who_updated_each_track() -> None:
    decoded = decode_vehicle_track_frame(vehicle_frame(3))
    assert not isinstance(decoded, Rejection), decoded
    msg = VehicleTrackMessage("fleet/veh01/@vehicle/tracks", *decoded, received_ns=5)
    line = vehicle_message_to_json(msg)
    assert (line["vehicle"], line["sensor"], line["seq"]) == ("veh01", "@vehicle", 3)
    assert line["source"] == {"sensor": "lidar", "seq": 3}
    assert line["sensors"] == {"lidar": "ok", "camera": "probation"}
    assert [t["id"] for t in line["tracks"]] == [7, 12]
    assert [t["existence"] for t in line["tracks"]] == [0.97, 0.5]
    stamp = msg.stamp_ns
    assert [t["updated_ns"] for t in line["tracks"]] == [
        {"lidar": stamp, "camera": stamp - 30_000_000},
        {"lidar": stamp},
    ]
    assert json.loads(json.dumps(line)) == line


def test_a_vehicles_tracks_answer_its_sensors_frames_up_to_their_stamp() -> None:
    marks = Watermarks()
    # Nothing heard yet: every frame waits.
    assert not marks.sent("v", "lidar", 0, 100)
    assert not marks.sent("v", "camera", 0, 100)
    assert not marks.sent("v", "camera", 1, 166)
    assert not marks.sent("v", "lidar", 1, 200)
    assert not marks.sent("w", "lidar", 0, 100)  # another vehicle
    # The message of lidar 0 (stamp 100): both sensors' frames up to 100.
    assert sorted(marks.heard("v", ["lidar", "camera"], 100)) == [
        ("v", "camera", 0),
        ("v", "lidar", 0),
    ]
    # Camera 1 only watched (no message); lidar 1's message at 200 answers both.
    assert sorted(marks.heard("v", ["lidar", "camera"], 200)) == [
        ("v", "camera", 1),
        ("v", "lidar", 1),
    ]
    # A frame sent after the vehicle passed its stamp (re-processed or refused late: no
    # message of its own) is answered at once; a later one waits; messages never go back.
    assert marks.sent("v", "camera", 2, 190)
    assert not marks.sent("v", "camera", 3, 250)
    assert marks.heard("v", ["lidar", "camera"], 150) == []
    # A sensor the vehicle does not fuse is answered by its own tracks, never here.
    assert not marks.sent("v", "radar", 0, 50)
    assert marks.heard("v", ["lidar", "camera"], 300) == [("v", "camera", 3)]


def test_replay_refuses_a_fused_stream_and_record_kitti_the_fused_tracks(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    rec = tmp_path / "r.mcap"
    rec.write_bytes(b"")
    err = one_line_error(capsys, "replay", "mcap", str(rec), "--sensors", "veh01/@vehicle")
    assert "veh01/@vehicle" in err and "'veh01/*'" in err
    err = one_line_error(
        capsys, "record", "--format", "kitti", "--keys", FUSED, "--out", str(tmp_path / "k")
    )
    assert "KITTI" in err and "jsonl or mcap" in err


# ------------------------------------------------------------------ through services
def fused_service(tmp: Path, name: str, config: Path) -> ServiceProcess:
    # Blocking intake: no frame is shed, so both runs see the same frames.
    state = tmp / name / "state"
    state.mkdir(parents=True)
    return start_service(
        tmp / name, "--config", str(config), "--backpressure", "block", "--state-dir",
        str(state), instance=f"fused-{name}",
    )  # fmt: skip


@dataclass
class FirstRun:
    path: Path
    wire: list[WireFrame]
    want: list[Any]  # the core's fused tracks on these frames in stamp order
    published: list[bytes]  # the fused tracks as the planner received them


def _wait_for_recorder(session: zenoh.Session) -> None:
    """The recorder (and only it) subscribes to the vehicle's errors keys: once a publisher
    there matches, it hears this session."""
    probe = session.declare_publisher(f"fleet/{VEHICLE}/lidar/errors")
    wait_for(lambda: probe.matching_status.matching, 10, "the recorder's subscription")
    probe.undeclare()  # type: ignore[no-untyped-call]


@pytest.fixture(scope="module")
def first(tmp_path_factory: pytest.TempPathFactory) -> Iterator[FirstRun]:
    """A vehicle's lidar and camera (frames with extrinsics) into a service that fuses them,
    its sensors and fused tracks recorded to MCAP, the fused tracks also heard by a planner."""
    tmp = tmp_path_factory.mktemp("fused")
    config = write_config(tmp)
    wire = frames(2.0, T0_NS)  # stamps in the past: none runs ahead of the service's clock
    want = expected(wire, fusion_of(config))
    svc = fused_service(tmp, "first", config)
    out = tmp / "first.mcap"
    published: list[bytes] = []
    lock = threading.Lock()

    def on_fused(sample: zenoh.Sample) -> None:
        with lock:
            published.append(sample.payload.to_bytes())

    try:
        # Zenoh peers route nobody else's samples: the vehicle reaches the recorder directly.
        listen = f"tcp/127.0.0.1:{free_port()}"
        rec = record(
            "--format", "mcap", "--out", str(out), "--connect", svc.endpoint, "--listen", listen,
            "--sensors", f"{VEHICLE}/*", "--frames", str(len(wire) + len(want)),
        )  # fmt: skip
        with open_session(mode="peer", connect=[svc.endpoint, listen]) as vehicle:
            planner = vehicle.declare_subscriber(FUSED, on_fused)
            pubs = {
                sensor: vehicle.declare_publisher(
                    f"fleet/{VEHICLE}/{sensor}/detections",
                    congestion_control=zenoh.CongestionControl.BLOCK,
                )
                for sensor in ("lidar", "camera")
            }
            for pub in pubs.values():
                wait_for(lambda p=pub: p.matching_status.matching, 10, "the service")
            _wait_for_recorder(vehicle)
            for f in wire:  # in stamp order, as the vehicle sends them
                pubs[f.sensor].put(f.payload())
            wait_for(lambda: len(published) >= len(want), 30, "every fused message")
            code, stdout, err = rec.wait()
            planner.undeclare()  # type: ignore[no-untyped-call]
        assert code == 0, err
        assert f"{len(wire) + len(want)} messages" in stdout, stdout
    finally:
        kill_leftovers()
        svc.stop()
    yield FirstRun(out, wire, want, published)


def fused_messages(messages: list[tuple[Any, Any, Any]]) -> list[tuple[Any, Any]]:
    out = []
    for _, channel, message in messages:
        if channel.topic == FUSED:
            decoded = decode_vehicle_track_frame(message.data)
            assert not isinstance(decoded, Rejection), decoded
            out.append(decoded)
    return out


def raw(messages: list[tuple[Any, Any, Any]], topic: str) -> list[bytes]:
    return [m.data for _, c, m in messages if c.topic == topic]


@pytest.mark.zenoh
def test_the_recording_holds_what_travelled_byte_for_byte(first: FirstRun) -> None:
    (summary, _), messages = read(first.path)
    channels = {c.topic: c for c in summary.channels.values() if c.message_encoding == "msgpack"}
    assert set(channels) == {
        f"fleet/{VEHICLE}/lidar/detections",
        f"fleet/{VEHICLE}/camera/detections",
        FUSED,
    }
    assert summary.schemas[channels[FUSED].schema_id].name == "VehicleTrackFrame"
    # The fused tracks: the planner's bytes, in its order (write, read back: exact).
    assert raw(messages, FUSED) == first.published and len(first.published) == len(first.want)
    for sensor in ("lidar", "camera"):
        sent = [f.payload() for f in first.wire if f.sensor == sensor]
        assert raw(messages, f"fleet/{VEHICLE}/{sensor}/detections") == sent
    # The service fused them as the core does in stamp order.
    fused = fused_messages(messages)
    assert [f.seq for f, _ in fused] == list(range(len(first.want)))
    for (_, got), want in zip(fused, first.want, strict=True):
        np.testing.assert_array_equal(got.id, want.id)
        np.testing.assert_array_equal(got.center, want.center)
        np.testing.assert_array_equal(got.existence, want.existence)
        np.testing.assert_array_equal(got.sensor_stamp_ns, want.sensor_stamp_ns)
    assert sum(len(t) for _, t in fused) > len(fused)  # cars were tracked, by both sensors
    assert any((t.sensor_stamp_ns >= 0).all(axis=1).any() for _, t in fused if len(t))


@pytest.mark.zenoh
def test_a_replayed_fused_recording_gives_the_same_fused_tracks(
    first: FirstRun, tmp_path: Path
) -> None:
    config = write_config(tmp_path)
    svc = fused_service(tmp_path, "again", config)
    n, m = len(first.wire), len(first.want)
    try:
        listen = f"tcp/127.0.0.1:{free_port()}"
        again = tmp_path / "again.mcap"
        rec = record(
            "--format", "mcap", "--out", str(again), "--connect", svc.endpoint, "--listen", listen,
            "--sensors", f"{VEHICLE}/*", "--frames", str(n + m), "--no-foxglove",
        )  # fmt: skip
        lines = record(
            "--keys", f"fleet/{VEHICLE}/*/tracks", "--out", str(tmp_path / "jsonl"),
            "--frames", str(m), "--connect", svc.endpoint,
        )  # fmt: skip
        done = cli(
            "replay", "mcap", str(first.path), "--rate", "max", "--connect", svc.endpoint,
            "--connect", listen,
        )  # fmt: skip
        assert done.returncode == 0, done.stdout + done.stderr
        assert f"{n}/{n} frames sent" in done.stdout, done.stdout
        assert f"{n} tracked ({n} into fused vehicles' tracks), 0 refused, 0 unanswered" in (
            done.stdout
        )
        code, stdout, err = rec.wait()
        assert code == 0, err
        assert f"{n + m} messages" in stdout, stdout
        code, stdout, err = lines.wait()
        assert code == 0, err
    finally:
        kill_leftovers()
        svc.stop()
    recorded, replayed = read(first.path)[1], read(again)[1]
    # The detections went out as recorded, byte for byte; the fused tracks were not sent.
    for sensor in ("lidar", "camera"):
        topic = f"fleet/{VEHICLE}/{sensor}/detections"
        assert raw(replayed, topic) == raw(recorded, topic)
    want, got = fused_messages(recorded), fused_messages(replayed)
    assert len(got) == len(want) == m
    for (w_frame, w), (g_frame, g) in zip(want, got, strict=True):
        for name in SAME_FIELDS:
            assert getattr(g_frame, name) == getattr(w_frame, name), (name, w_frame.seq)
        assert g.classes == w.classes
        for spec in VEHICLE_TRACK_COLUMNS:
            np.testing.assert_array_equal(
                getattr(g, spec.name), getattr(w, spec.name), err_msg=spec.name
            )
    # The JSON lines recording of the same run: one line per fused message.
    jsonl = [json.loads(x) for x in (tmp_path / "jsonl" / "tracks.jsonl").read_text().splitlines()]
    assert [(o["sensor"], o["seq"]) for o in jsonl] == [("@vehicle", k) for k in range(m)]
    for obj, (frame, tracks) in zip(jsonl, got, strict=True):
        assert obj["source"] == {"sensor": frame.sensor, "seq": frame.sensor_seq}
        assert [t["id"] for t in obj["tracks"]] == tracks.id.tolist()
        assert [t["existence"] for t in obj["tracks"]] == [
            round(e, 4) for e in tracks.existence.tolist()
        ]
