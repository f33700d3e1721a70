"""Recordings made before the JSON twins became rows still replay: ``recorded-83a030f.mcap``
(tests/mcap/fixtures/README.md: made by the code of commit 83a030f, its service and its
recorder) replayed into a current service is answered frame for frame with the tracks it
recorded, and its raw messages still give today's twins and ROS 2 messages."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from mcap.reader import make_reader

from simpletrack.cli.replay_mcap import load
from simpletrack.mcap.format import schema_name, split_key
from simpletrack.mcap.foxglove import FoxgloveChannels
from simpletrack.ros2.recording import AutowareMessages
from tests.cli.test_record_mcap import kill_leftovers, read, record, service, tracks_by_frame
from tests.cli.test_replay_record import cli
from tests.mcap.twins import check_twin
from tests.service_helpers import ROOT

FIXTURE = ROOT / "tests" / "mcap" / "fixtures" / "recorded-83a030f.mcap"
LIDAR, RADAR = 12, 8


def test_the_old_recording_loads_and_its_messages_still_convert() -> None:
    frames = load(FIXTURE, None)
    assert [(r.sensor, r.seq) for r in frames if r.sensor == "lidar"] == [
        ("lidar", k) for k in range(LIDAR)
    ]
    assert [r.seq for r in frames if r.sensor == "radar"] == list(range(RADAR))
    assert {(r.prefix, r.vehicle) for r in frames} == {("fleet", "veh01")}
    channels = FoxgloveChannels()
    ros2 = AutowareMessages()
    old_twins = 0
    with open(FIXTURE, "rb") as f:
        reader = make_reader(f)
        metadata = {m.name: dict(m.metadata) for m in reader.iter_metadata()}
        assert (
            metadata["simpletrack"]["foxglove"] == "true" and "ros2" not in metadata["simpletrack"]
        )
        for _, channel, message in reader.iter_messages(log_time_order=True):
            if channel.topic.endswith("/json"):  # then: the map as it was, bins as base64
                assert isinstance(json.loads(message.data).get("boxes", {"c": 0}), dict)
                old_twins += 1
            parts = split_key(channel.topic)
            if parts is None or channel.message_encoding != "msgpack":
                continue
            _, vehicle, sensor, leaf = parts
            derived = channels.derive(channel.topic, leaf, vehicle, sensor, message.data)
            twin = json.loads(derived[0].data)
            check_twin(twin, message.data, schema_name(sensor, leaf))
            converted = ros2.convert(leaf, vehicle, sensor, message.data)
            assert converted is not None and converted[1]
    assert old_twins == 2 * (LIDAR + RADAR)


@pytest.mark.zenoh
def test_the_old_recording_replays_into_a_current_service_to_its_tracks(tmp_path: Path) -> None:
    n = LIDAR + RADAR
    svc = service(tmp_path, "legacy")  # the kitti preset, as when it was made
    try:
        out = tmp_path / "again.mcap"
        rec = record(
            "--format", "mcap", "--out", str(out), "--connect", svc.endpoint,
            "--what", "tracks", "--frames", str(n), "--no-foxglove",
        )  # fmt: skip
        done = cli("replay", "mcap", str(FIXTURE), "--rate", "max", "--connect", svc.endpoint)
        assert done.returncode == 0, done.stdout + done.stderr
        assert f"2 stream(s), {n}/{n} frames sent" in done.stdout, done.stdout
        assert f"{n} tracked, 0 refused, 0 unanswered" in done.stdout, done.stdout
        code, _, err = rec.wait()
        assert code == 0, err
    finally:
        kill_leftovers()
        svc.stop()
    want = tracks_by_frame(read(FIXTURE)[1])
    got = tracks_by_frame(read(out)[1])
    assert sorted(got) == sorted(want) and len(want) == n
    for frame, (ids, classes, center, size, yaw, state) in want.items():
        g_ids, g_classes, g_center, g_size, g_yaw, g_state = got[frame]
        assert (g_ids, g_classes, g_state) == (ids, classes, state), frame
        np.testing.assert_array_equal(g_center, center, err_msg=str(frame))
        np.testing.assert_array_equal(g_size, size)
        np.testing.assert_array_equal(g_yaw, yaw)
    assert {len(v[0]) for k, v in want.items() if k[0] == "lidar"} == {3}  # all three tracked
