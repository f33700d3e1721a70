"""``simpletrack status`` shows the group: both members, each one's view, the sensors each
owns (together: every sensor, once), and says so when nobody answers."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

from simpletrack.spawn import free_port
from tests.scale.fleet import Group
from tests.service_helpers import ROOT, Client, moving_cars, stamp, wait_for

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
