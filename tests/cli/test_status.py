"""``simpletrack status`` shows the group: both members, each one's view, the sensors each
owns (together: every sensor, once), and says so when nobody answers."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

from simpletrack.spawn import free_port
from tests.scale.fleet import Group
from tests.service_helpers import ROOT, Client, moving_cars, stamp, start_service, wait_for

SENSORS = [f"car-{i}" for i in range(8)]


def status(*args: str) -> subprocess.CompletedProcess[str]:
    cmd = [sys.executable, "-m", "simpletrack.cli.main", "status", *args]
    return subprocess.run(cmd, cwd=ROOT, capture_output=True, text=True, timeout=60)


def test_status_lists_the_members_and_splits_the_sensors_between_them(tmp_path: Path) -> None:
    group = Group(tmp_path)
    try:
        group.add("m-a")
        group.add("m-b")
        cli = Client(group.endpoints()[0])
        try:
            # Peers route nothing for each other: the vehicle reaches m-b once gossip has
            # connected it there, and a frame of m-b's sent before that reaches nobody.
            wait_for(
                lambda: (
                    sum(1 for r in cli.session.liveliness().get("fleet/@simpletrack/*") if r.ok)
                    == 2
                ),
                20,
                "both members reachable",
            )
            for k in range(3):
                for v in SENSORS:
                    cli.send(v, "lidar", k, stamp(k), moving_cars(k))
            wait_for(lambda: all(cli.received.n_tracks(f"{v}/lidar") == 3 for v in SENSORS), 20)
        finally:
            cli.session.close()
        out = status("--connect", group.endpoints()[1], "--json")
        assert out.returncode == 0, out.stderr
        statuses = [json.loads(line) for line in out.stdout.splitlines()]
        assert sorted(s["instance"] for s in statuses) == ["m-a", "m-b"]
        assert all(s["members"] == ["m-a", "m-b"] for s in statuses)
        owned = [f"{x['vehicle']}" for s in statuses for x in s["sensors"]]
        assert sorted(owned) == sorted(SENSORS)
        assert all(s["sensors"] for s in statuses), "rendezvous put every sensor on one member"
        text = status("--connect", group.endpoints()[0], "--sensors")
        assert text.returncode == 0
        assert "m-a  ready  members=m-a,m-b" in text.stdout
        assert "car-0/lidar" in text.stdout
    finally:
        group.stop_all()


def test_status_with_nobody_answering_says_so_and_fails() -> None:
    out = status("--connect", f"tcp/127.0.0.1:{free_port()}", "--timeout", "0.5")
    assert out.returncode == 1
    assert "no instance answered" in out.stderr


def test_status_shows_each_sensors_rate_last_seq_and_resets(tmp_path: Path) -> None:
    svc = start_service(tmp_path, env={"SIMPLETRACK_RESET_GAP_S": "3"}, instance="st-one")
    try:
        cli = Client(svc.endpoint)
        try:
            for k in range(4):
                cli.send("car-r", "lidar", k, stamp(k), moving_cars(k))
            # 10 s of stamps skipped (reset_gap_s 3): a new tracker for this sensor.
            for k in range(100, 103):
                cli.send("car-r", "lidar", k, stamp(k), moving_cars(k))
            cli.send("car-q", "lidar", 0, stamp(0), moving_cars(0))
            wait_for(
                lambda: (
                    cli.received.n_tracks("car-r/lidar") == 7
                    and cli.received.n_tracks("car-q/lidar") == 1
                ),
                20,
                "8 frames",
            )
        finally:
            cli.close()
        out = status("--connect", svc.endpoint, "--json")
        assert out.returncode == 0, out.stderr
        [reply] = [json.loads(line) for line in out.stdout.splitlines()]
        sensors = {x["vehicle"]: x for x in reply["sensors"]}
        assert (sensors["car-r"]["last_seq"], sensors["car-r"]["resets"]) == (102, 1)
        assert sensors["car-r"]["rate_hz"] > 0
        assert (sensors["car-q"]["resets"], sensors["car-q"]["rate_hz"]) == (0, 0.0)

        text = status("--connect", svc.endpoint, "--sensors")
        assert text.returncode == 0, text.stderr
        [line] = [x for x in text.stdout.splitlines() if "car-r/lidar" in x]
        assert "seq=102" in line and "resets=1" in line and "frames=7" in line
        assert "stamp=2023-11-14T22:13:30.200Z" in line  # stamp(102), UTC
        assert "rate=0.0/s" not in line
    finally:
        svc.stop()
