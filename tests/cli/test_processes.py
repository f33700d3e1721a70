"""``simpletrack serve --processes N``: real supervisor and child processes over real Zenoh on
127.0.0.1 (multicast scouting off). What an operator relies on: every member answers
readiness, a vehicle connected to child 0 reaches them all, SIGTERM stops the group cleanly,
a killed child comes back, a bad N is refused in one line."""

from __future__ import annotations

import argparse
import contextlib
import os
import signal
import socket
import subprocess
import sys
import urllib.error
import urllib.request
from collections.abc import Iterator
from pathlib import Path

import pytest

from simpletrack.cli.main import build_parser, main
from simpletrack.cli.processes import (
    CRASH_WINDOW_S,
    RESTARTS_PER_WINDOW,
    RestartPolicy,
    child_specs,
    passed_on,
    refused,
)
from simpletrack.cli.serve import settings_from_args
from simpletrack.spawn import free_run
from simpletrack.wire import Rejection, ServiceStatus, decode_message
from tests.service_helpers import (
    ROOT,
    Client,
    ServiceProcess,
    metric,
    moving_cars,
    stamp,
    wait_for,
)

INSTANCE = "grp"


class Group:
    """A running ``serve --processes N`` (a ServiceProcess for the supervisor and child 0)."""

    def __init__(self, tmp: Path, n: int, *extra: str) -> None:
        self.n = n
        self.port, self.metrics_port = free_run(n), free_run(n)
        self.endpoint = f"tcp/127.0.0.1:{self.port}"
        log_path = tmp / f"group-{self.port}.log"
        cmd = [
            *(sys.executable, "-m", "simpletrack.cli.main", "serve", "--processes", str(n)),
            *("--listen", self.endpoint, "--metrics-port", str(self.metrics_port)),
            *("--instance", INSTANCE, *extra),
        ]
        env = {**os.environ, "SIMPLETRACK_LOG_FORMAT": "json", "NO_COLOR": "1"}
        with open(log_path, "wb") as log:
            proc = subprocess.Popen(cmd, cwd=ROOT, env=env, stdout=log, stderr=log)
        self.svc = ServiceProcess(proc, self.endpoint, self.metrics_port, log_path, INSTANCE)

    def ready(self, i: int) -> bool:
        try:
            url = f"http://127.0.0.1:{self.metrics_port + i}/readyz"
            with urllib.request.urlopen(url, timeout=2) as r:
                return int(r.status) == 200
        except (OSError, urllib.error.HTTPError):
            return False

    def wait_ready(self) -> None:
        def all_ready() -> bool:
            if self.svc.proc.poll() is not None:
                raise AssertionError(f"supervisor exited:\n{self.svc.log_path.read_text()}")
            return all(self.ready(i) for i in range(self.n))

        wait_for(all_ready, 90, "every member's /readyz")

    def events(self, name: str) -> list[dict[str, object]]:
        return [e for e in self.svc.logs() if e.get("event") == name]

    def pids(self, child: int) -> list[int]:
        return [int(str(e["pid"])) for e in self.events("child_started") if e["child"] == child]

    def metrics(self, i: int) -> dict[str, float]:
        return ServiceProcess(
            self.svc.proc, "", self.metrics_port + i, self.svc.log_path, ""
        ).metrics()


def alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    # A zombie is dead for the purpose: only its parent's wait is missing.
    with contextlib.suppress(OSError):
        return Path(f"/proc/{pid}/stat").read_text().split(") ")[1][0] != "Z"
    return False


@contextlib.contextmanager
def group(tmp: Path, n: int, *extra: str) -> Iterator[Group]:
    g = Group(tmp, n, *extra)
    try:
        g.wait_ready()
        yield g
    finally:
        if g.svc.proc.poll() is None:
            g.svc.stop(signal.SIGKILL)  # prctl's death signal then stops the children


@pytest.mark.zenoh
def test_two_members_are_ready_reach_each_other_and_stop_cleanly(tmp_path: Path) -> None:
    with group(tmp_path, 2) as g:
        pids = [g.pids(0)[-1], g.pids(1)[-1]]
        assert len(set(pids)) == 2 and g.svc.proc.pid not in pids
        instances = {e["instance"] for e in g.events("child_started")}
        assert instances == {f"{INSTANCE}-0", f"{INSTANCE}-1"}

        # A vehicle and a planner connected to child 0's endpoint alone.
        c = Client(g.endpoint)
        try:
            want = {f"{INSTANCE}-0", f"{INSTANCE}-1"}

            def statuses() -> set[str]:
                out = set()
                for raw in c.get("fleet/@simpletrack/*/status", timeout=2.0):
                    s = decode_message(raw, ServiceStatus)
                    if not isinstance(s, Rejection):
                        out.add(s.instance)
                return out

            wait_for(lambda: statuses() == want, 30, "both members' status replies")
            sensors = [f"s{i}" for i in range(6)]
            k = 0

            def every_member_heard_every_sensor() -> bool:
                nonlocal k
                for s in sensors:
                    c.send("van", s, k, stamp(k), moving_cars(k))
                k += 1
                return all(
                    metric(g.metrics(i), "simpletrack_frames_received_total") > 0 for i in range(2)
                )

            wait_for(every_member_heard_every_sensor, 30, "frames at both members")
            wait_for(lambda: all(c.received.n_tracks(f"van/{s}") > 0 for s in sensors), 30)
        finally:
            c.close()

        assert g.svc.stop(signal.SIGTERM, timeout=60) == 0
        assert not [p for p in pids if alive(p)], "a child outlived the supervisor"
        exited = {int(str(e["child"])): e["code"] for e in g.events("child_exited")}
        assert exited == {0: 0, 1: 0}
        assert sum(1 for e in g.svc.logs() if e.get("event") == "service_stopped") == 2
        assert not g.events("child_died")


@pytest.mark.zenoh
def test_a_killed_child_is_restarted_and_answers_again(tmp_path: Path) -> None:
    with group(tmp_path, 2) as g:
        old = g.pids(1)[-1]
        os.kill(old, signal.SIGKILL)
        wait_for(lambda: len(g.pids(1)) == 2, 30, "a second start of child 1")
        new = g.pids(1)[-1]
        assert new != old and alive(new)
        wait_for(lambda: g.ready(1), 60, "the restarted child's /readyz")
        died = g.events("child_died")
        assert [(e["child"], e["pid"], e["code"]) for e in died] == [(1, old, 128 + 9)]
        assert g.events("child_restarting")[0]["child"] == 1
        assert g.pids(0) == g.pids(0)[:1], "the sibling was left alone"
        # It is a member again: a vehicle on child 0's endpoint reaches it.
        c = Client(g.endpoint)
        try:
            k = 0

            def restarted_child_hears_frames() -> bool:
                nonlocal k
                c.send("van", "lidar", k, stamp(k), moving_cars(k))
                k += 1
                return metric(g.metrics(1), "simpletrack_frames_received_total") > 0

            wait_for(restarted_child_hears_frames, 30, "frames at the restarted child")
        finally:
            c.close()
        assert g.svc.stop(signal.SIGTERM, timeout=60) == 0
        assert not alive(new)


@pytest.mark.zenoh
def test_a_child_refused_at_its_first_start_stops_the_group_at_once_with_its_error(
    tmp_path: Path,
) -> None:
    # Child 1's metrics port is held from the start: its arguments can never run, and
    # restarting it five times over ~20 s would only hide the reason.
    g = Group(tmp_path, 2)
    with socket.socket() as blocker:
        blocker.bind(("127.0.0.1", g.metrics_port + 1))
        blocker.listen()
        try:
            code = g.svc.proc.wait(90)
        except subprocess.TimeoutExpired:
            g.svc.stop(signal.SIGKILL)
            raise AssertionError(f"the group ran on:\n{g.svc.log_path.read_text()}") from None
    assert code == 2
    assert [e["child"] for e in g.events("child_refused")] == [1]
    assert len(g.pids(1)) == 1 and not g.events("child_died") and not g.events("crash_loop")
    assert f"metrics port {g.metrics_port + 1} on 127.0.0.1 is in use" in g.svc.log_path.read_text()
    assert not [p for p in g.pids(0) + g.pids(1) if alive(p)]


@pytest.mark.zenoh
def test_a_child_that_keeps_dying_stops_the_group_non_zero(tmp_path: Path) -> None:
    # Child 1 ran, was killed, and its metrics port was taken meanwhile: each restart is
    # refused (a restart's refusal is retried: what holds the port may let go), until the
    # crash loop gives up.
    with group(tmp_path, 2) as g, socket.socket() as blocker:
        os.kill(g.pids(1)[0], signal.SIGKILL)
        # Readiness probes leave connections in TIME_WAIT on the port.
        blocker.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)

        def port_taken() -> bool:
            try:
                blocker.bind(("127.0.0.1", g.metrics_port + 1))
            except OSError:
                return False
            blocker.listen()
            return True

        wait_for(port_taken, 5, "child 1's metrics port, freed by its death")
        try:
            code = g.svc.proc.wait(CRASH_WINDOW_S + 60)
        except subprocess.TimeoutExpired:
            raise AssertionError(f"no crash loop:\n{g.svc.log_path.read_text()}") from None
    assert code != 0
    died = g.events("child_died")
    assert len(died) == RESTARTS_PER_WINDOW + 1
    assert [e["code"] for e in died] == [128 + 9] + [2] * RESTARTS_PER_WINDOW
    assert g.events("crash_loop")[0]["child"] == 1 and not g.events("child_refused")
    assert not [p for p in g.pids(0) + g.pids(1) if alive(p)]


@pytest.mark.parametrize("n", ["0", "-3", "two", "65", "1.5"])
def test_a_bad_process_count_is_refused_in_one_line(
    n: str, capsys: pytest.CaptureFixture[str]
) -> None:
    assert main(["serve", "--processes", n]) == 2
    err = capsys.readouterr().err.strip()
    assert err == f"simpletrack serve: error: --processes {n!r} must be an integer in 1..64 or auto"


def test_ports_past_the_last_one_are_refused(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["serve", "--processes", "3", "--metrics-port", "65534"]) == 2
    assert "--metrics-port 65534 + 2 is past port 65535" in capsys.readouterr().err
    assert main(["serve", "--processes", "2", "--listen", "tcp/127.0.0.1:0"]) == 2
    assert "'tcp/127.0.0.1:0' (port 0)" in capsys.readouterr().err


def _serve_args(*argv: str) -> tuple[argparse.ArgumentParser, argparse.Namespace]:
    args = build_parser().parse_args(["serve", *argv])
    return args.serve_parser, args


def test_each_child_gets_its_own_instance_ports_and_state_the_rest_as_given(
    tmp_path: Path,
) -> None:
    parser, args = _serve_args(
        *("--processes", "3", "--listen", "tcp/0.0.0.0:7447", "--connect", "tcp/10.0.0.9:7447"),
        *("--metrics-port=9464", "--state-dir", str(tmp_path), "--inst", "edge"),
        *("--prefix", "fleet/eu", "--preset", "nuscenes", "--workers", "1"),
    )
    specs = child_specs(settings_from_args(args), passed_on(parser, args), 3)
    child = list(specs[1].argv)

    def values(flag: str) -> list[str]:
        return [child[i + 1] for i, w in enumerate(child) if w == flag]

    assert [s.instance for s in specs] == ["edge-0", "edge-1", "edge-2"]
    assert values("--instance") == ["edge-1"]
    assert values("--metrics-port") == ["9465"]
    assert values("--state-dir") == [str(tmp_path / "1")]
    assert values("--listen") == ["tcp/0.0.0.0:7448"]
    assert values("--connect") == ["tcp/10.0.0.9:7447", "tcp/127.0.0.1:7447", "tcp/127.0.0.1:7449"]
    assert values("--prefix") == ["fleet/eu"] and values("--preset") == ["nuscenes"]
    assert values("--workers") == ["1"]
    assert "--processes" not in child
    assert list(specs[0].argv)[list(specs[0].argv).index("--listen") + 1] == "tcp/0.0.0.0:7447"


def test_client_mode_children_share_the_routers_and_do_not_listen() -> None:
    parser, args = _serve_args(
        "--processes",
        "2",
        "--mode",
        "client",
        "--connect",
        "tcp/router:7447",
        "--metrics-port",
        "0",
    )
    specs = child_specs(settings_from_args(args), passed_on(parser, args), 2)
    for spec in specs:
        argv = list(spec.argv)
        assert "--listen" not in argv
        assert argv.count("--connect") == 1 and "tcp/router:7447" in argv
        assert argv[argv.index("--metrics-port") + 1] == "0"


@pytest.mark.parametrize(
    ("code", "starts", "stop_at_once"),
    [
        (2, 1, True),  # a usage error at the first start: the arguments cannot run
        (2, 2, False),  # after a run: retried, with back-off
        (1, 1, False),  # a crash
        (0, 1, False),  # exited unasked
        (128 + 9, 1, False),  # killed
        (128 + 15, 3, False),
    ],
)
def test_only_a_first_start_refused_as_a_usage_error_stops_the_group_at_once(
    code: int, starts: int, stop_at_once: bool
) -> None:
    assert refused(code, starts) is stop_at_once


def test_restarts_back_off_and_a_crash_loop_gives_up() -> None:
    policy = RestartPolicy()
    delays = [policy.after_death(float(t)) for t in range(RESTARTS_PER_WINDOW)]
    assert delays == sorted(delays) and delays[0] is not None and delays[0] < delays[-1]  # type: ignore[operator]
    assert policy.after_death(float(RESTARTS_PER_WINDOW)) is None
    # Deaths spread wider than the window are forgiven.
    spread = RestartPolicy()
    assert all(spread.after_death(t * CRASH_WINDOW_S) is not None for t in range(20))
