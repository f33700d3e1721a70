"""MCAP recordings around real services: ``record --format mcap`` writes what travelled, byte
for byte, in a file the ``mcap`` reader opens; ``replay mcap`` of those detections into a fresh
service gives the same tracks; SIGTERM leaves a complete file; bad files are one-line errors."""

from __future__ import annotations

import signal
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from mcap.reader import make_reader
from mcap.writer import Writer

from simpletrack.wire import Rejection, decode_detection_frame, decode_track_frame
from simpletrack.wire.header import peek_header
from tests.cli.test_replay_record import Recorder, cli, one_line_error, write_kitti_like
from tests.service_helpers import (
    ROOT,
    Client,
    ServiceProcess,
    free_port,
    moving_cars,
    stamp,
    start_service,
    wait_for,
)

pytestmark = pytest.mark.zenoh
SEQS = {"0100": 14, "0101": 9}
N = sum(SEQS.values())


_STARTED: list[Recorder] = []


def record(*args: str) -> Recorder:
    rec = Recorder(*args)
    _STARTED.append(rec)
    return rec


def kill_leftovers() -> None:
    """A recorder the test did not see to its end (it failed first) must not outlive it."""
    while _STARTED:
        rec = _STARTED.pop()
        if rec.proc.poll() is None:
            rec.proc.kill()
            rec.proc.communicate()


def service(tmp: Path, name: str) -> ServiceProcess:
    # Blocking intake: no frame is shed, so two runs see the same frames.
    state = tmp / name / "state"
    state.mkdir(parents=True)
    return start_service(
        tmp / name, "--preset", "kitti", "--backpressure", "block", "--state-dir", str(state),
        instance=f"mcap-{name}",
    )  # fmt: skip


def read(path: Path) -> tuple[Any, list[tuple[Any, Any, Any]]]:
    with open(path, "rb") as f:
        reader = make_reader(f)
        summary = reader.get_summary()
        messages = list(reader.iter_messages(log_time_order=True))
        metadata = {m.name: dict(m.metadata) for m in reader.iter_metadata()}
    return (summary, metadata), messages


def tracks_by_frame(messages: list[tuple[Any, Any, Any]]) -> dict[tuple[str, int], Any]:
    """Each sensor's track frames (not a fused vehicle's, ``@vehicle``) by (sensor, seq)."""
    out = {}
    for _, channel, message in messages:
        if channel.topic.endswith("/tracks") and not channel.topic.endswith("/@vehicle/tracks"):
            decoded = decode_track_frame(message.data)
            assert not isinstance(decoded, Rejection), decoded
            frame, arrays = decoded
            order = np.argsort(arrays.id)
            out[(frame.sensor, frame.seq)] = (
                arrays.id[order].tolist(),
                arrays.class_index[order].tolist(),
                arrays.center[order],
                arrays.size[order],
                arrays.yaw[order],
                arrays.state[order].tolist(),
            )
    return out


@pytest.fixture(scope="module")
def recorded(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Path]:
    """A KITTI-layout replay to a real service, its detections and tracks recorded to MCAP."""
    tmp = tmp_path_factory.mktemp("mcap")
    write_kitti_like(tmp / "kitti", SEQS)
    svc = service(tmp, "first")
    try:
        out = tmp / "first.mcap"
        # Zenoh peers route nobody else's samples: the vehicle (replay) reaches the recorder
        # directly, as it would through a router in the field.
        recorder = f"tcp/127.0.0.1:{free_port()}"
        rec = record(
            "--format", "mcap", "--out", str(out), "--connect", svc.endpoint, "--listen", recorder,
            "--sensors", "synth/*", "--what", "detections,tracks", "--frames", str(2 * N),
        )  # fmt: skip
        done = cli(
            "replay", "kitti", "--data", str(tmp / "kitti"), "--seqs", ",".join(SEQS),
            "--classes", "Car", "--vehicle", "synth", "--rate", "max", "--connect", svc.endpoint,
            "--connect", recorder,
        )  # fmt: skip
        assert done.returncode == 0, done.stdout + done.stderr
        code, stdout, err = rec.wait()
        assert code == 0, err
        assert f"{2 * N} messages" in stdout, stdout
    finally:
        kill_leftovers()
        svc.stop()
    yield out


def test_recording_holds_the_payloads_with_schemas(recorded: Path) -> None:
    (summary, metadata), messages = read(recorded)
    assert summary is not None  # finished: indexed, with statistics
    raw = {i: c for i, c in summary.channels.items() if c.message_encoding == "msgpack"}
    assert sum(summary.statistics.channel_message_counts[i] for i in raw) == 2 * N
    topics = {c.topic for c in raw.values()}
    assert topics == {f"fleet/synth/{s}/{leaf}" for s in SEQS for leaf in ("detections", "tracks")}
    # The Foxglove twins (tests/cli/test_record_mcap_foxglove.py) sit on their own topics.
    assert {c.topic for c in summary.channels.values()} - topics == {
        f"{t}/{twin}" for t in topics for twin in ("json", "scene")
    }
    schemas = {
        summary.schemas[c.schema_id].name: summary.schemas[c.schema_id] for c in raw.values()
    }
    assert sorted(schemas) == ["DetectionFrame", "TrackFrame"]
    for name, schema in schemas.items():
        assert schema.encoding == "jsonschema"
        assert schema.data == (ROOT / "schemas" / "json" / f"{name}.schema.json").read_bytes()
    for channel in raw.values():
        want = "DetectionFrame" if channel.topic.endswith("detections") else "TrackFrame"
        assert summary.schemas[channel.schema_id].name == want
    assert metadata["simpletrack"]["tool"] == "simpletrack record"
    assert metadata["simpletrack"]["prefix"] == "fleet"
    assert metadata["simpletrack"]["version"]

    seqs: dict[str, list[int]] = {}
    for _, channel, message in messages:
        if channel.message_encoding != "msgpack":
            continue
        seq, stamp = peek_header(message.data)
        assert seq is not None and stamp is not None
        assert (message.sequence, message.publish_time) == (seq, stamp)
        if channel.topic.endswith("/detections"):
            frame = decode_detection_frame(message.data)
            assert not isinstance(frame, Rejection), frame
            assert channel.topic == f"fleet/synth/{frame.frame.sensor}/detections"
            seqs.setdefault(frame.frame.sensor, []).append(seq)
    assert seqs == {s: list(range(n)) for s, n in SEQS.items()}


def test_replayed_detections_give_the_recorded_tracks(recorded: Path, tmp_path: Path) -> None:
    svc = service(tmp_path, "fresh")
    try:
        out = tmp_path / "replayed.mcap"
        rec = record(
            "--format", "mcap", "--out", str(out), "--connect", svc.endpoint,
            "--what", "tracks", "--frames", str(N),
        )  # fmt: skip
        done = cli("replay", "mcap", str(recorded), "--rate", "max", "--connect", svc.endpoint)
        assert done.returncode == 0, done.stdout + done.stderr
        assert f"{N}/{N} frames sent" in done.stdout and f"{N} tracked, 0 refused" in done.stdout
        code, _, err = rec.wait()
        assert code == 0, err
    finally:
        kill_leftovers()
        svc.stop()
    want = tracks_by_frame(read(recorded)[1])
    got = tracks_by_frame(read(out)[1])
    assert sorted(got) == sorted(want) and len(want) == N
    for frame, (ids, classes, center, size, yaw, state) in want.items():
        g_ids, g_classes, g_center, g_size, g_yaw, g_state = got[frame]
        assert (g_ids, g_classes, g_state) == (ids, classes, state), frame
        np.testing.assert_array_equal(g_center, center)
        np.testing.assert_array_equal(g_size, size)
        np.testing.assert_array_equal(g_yaw, yaw)
    assert any(len(v[0]) == 2 for v in want.values())  # the tracker did confirm the two cars


def test_sigterm_during_recording_leaves_a_complete_file(tmp_path: Path) -> None:
    svc = service(tmp_path, "term")
    client = Client(svc.endpoint)
    try:
        out = tmp_path / "term.mcap"
        rec = record(
            "--format", "mcap", "--out", str(out), "--connect", svc.endpoint,
            "--what", "tracks,errors", "--no-foxglove",
        )  # fmt: skip
        for k in range(5):
            client.send("veh", "lidar", k, stamp(k), moving_cars(k, 2))
            time.sleep(0.3)  # spread over 1.5 s: the later frames find the recorder listening
        wait_for(lambda: client.received.n_tracks("veh/lidar") == 5, 30, "5 track frames")
        rec.proc.send_signal(signal.SIGTERM)
        code, stdout, err = rec.wait()
    finally:
        kill_leftovers()
        client.close()
        svc.stop()
    assert code == 0, err
    (summary, metadata), messages = read(out)
    # The recorder's subscription reaches the service some time after it says "recording"
    # (no signal tells when: a loaded machine took over 0.5 s); what it heard, it kept whole.
    n = len(messages)
    assert f"interrupted: {n} messages" in stdout, stdout
    assert n >= 1 and summary is not None and summary.statistics.message_count == n
    assert {c.topic for c in summary.channels.values()} == {"fleet/veh/lidar/tracks"}
    assert metadata["simpletrack"]["foxglove"] == "false"
    assert [peek_header(m.data)[0] for _, _, m in messages] == list(range(5 - n, 5))


def test_replay_mcap_refuses_bad_files_in_one_line(
    recorded: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    assert "no such file" in one_line_error(capsys, "replay", "mcap", str(tmp_path / "no.mcap"))
    garbage = tmp_path / "garbage.mcap"
    garbage.write_bytes(b"not an mcap file at all" * 10)
    assert "not a readable MCAP file" in one_line_error(capsys, "replay", "mcap", str(garbage))
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(recorded.read_bytes()[: recorded.stat().st_size // 2])
    assert "not a readable MCAP file" in one_line_error(capsys, "replay", "mcap", str(cut))
    tracks_only = tmp_path / "tracks.mcap"
    with open(tracks_only, "wb") as f:
        writer = Writer(f)
        writer.start()
        schema = writer.register_schema("TrackFrame", "jsonschema", b"{}")
        channel = writer.register_channel("fleet/v/s/tracks", "msgpack", schema)
        writer.add_message(channel, log_time=1, data=b"\x80", publish_time=1)
        writer.finish()
    assert "no detections channels" in one_line_error(capsys, "replay", "mcap", str(tracks_only))
    err = one_line_error(capsys, "replay", "mcap", str(recorded), "--sensors", "synth/0999")
    assert "synth/0999" in err and "synth/0100" in err
    assert "FILE.mcap" in one_line_error(capsys, "replay", "mcap")
    assert "--rate" in one_line_error(capsys, "replay", "mcap", str(recorded), "--rate", "soon")


def test_record_mcap_refuses_mistakes_in_one_line(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    out = str(tmp_path / "r.mcap")
    base = ("record", "--format", "mcap", "--out", out)
    assert "--keys" in one_line_error(capsys, *base, "--keys", "fleet/*/*/tracks")
    assert "veh/a b" in one_line_error(capsys, *base, "--sensors", "veh/a b")
    assert "veh/@other" in one_line_error(capsys, *base, "--sensors", "veh/@other")
    assert "tracks only" in one_line_error(
        capsys, *base, "--sensors", "veh/@vehicle", "--what", "detections,errors"
    )
    assert "'pose'" in one_line_error(capsys, *base, "--what", "tracks,pose")
    assert "folder" in one_line_error(capsys, "record", "--format", "mcap", "--out", str(tmp_path))
    assert "mcap only" in one_line_error(
        capsys, "record", "--out", str(tmp_path / "j"), "--sensors", "v/s"
    )
    assert "--no-foxglove" in one_line_error(
        capsys, "record", "--out", str(tmp_path / "j"), "--no-foxglove"
    )
