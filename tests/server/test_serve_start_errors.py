"""``simpletrack serve`` as an operator starts it: list settings from the environment in the
form a shell or a manifest writes, and one-line errors (exit 2) naming what to change when a
variable or the metrics port is wrong."""

from __future__ import annotations

import os
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

from simpletrack.spawn import free_port, free_run
from simpletrack.wire import Rejection, ServiceStatus, decode_message
from tests.service_helpers import ROOT, ServiceProcess, client

SERVE = [sys.executable, "-m", "simpletrack.cli.main", "serve"]


def serve(*args: str, env: dict[str, str]) -> subprocess.CompletedProcess[str]:
    full_env = {**os.environ, "NO_COLOR": "1", **env}
    return subprocess.run(
        [*SERVE, *args], cwd=ROOT, env=full_env, capture_output=True, text=True, timeout=60
    )


def error_line(out: subprocess.CompletedProcess[str]) -> str:
    """The command's own error: the last line (the service's JSON log lines come first)."""
    lines = out.stderr.strip().splitlines()
    assert lines, out
    assert "Traceback" not in out.stderr, out.stderr
    return lines[-1]


def test_a_comma_separated_listen_list_from_the_environment_listens_on_each(
    tmp_path: Path,
) -> None:
    first = free_run(2)
    endpoints = [f"tcp/127.0.0.1:{first}", f"tcp/127.0.0.1:{first + 1}"]
    metrics_port = free_port()
    log_path = tmp_path / "serve.log"
    env = {
        **os.environ,
        "SIMPLETRACK_LOG_FORMAT": "json",
        "SIMPLETRACK_ZENOH__LISTEN": " , ".join(endpoints),
    }
    cmd = [*SERVE, "--metrics-port", str(metrics_port), "--instance", "env-list"]
    with open(log_path, "wb") as log:
        proc = subprocess.Popen(cmd, cwd=ROOT, env=env, stdout=log, stderr=log)
    svc = ServiceProcess(proc, endpoints[0], metrics_port, log_path, "env-list")
    try:
        deadline = time.monotonic() + 60
        while True:
            assert proc.poll() is None, log_path.read_text()
            try:
                if svc.http("/readyz")[0] == 200:
                    break
            except OSError:
                pass
            assert time.monotonic() < deadline, log_path.read_text()
            time.sleep(0.05)
        for endpoint in endpoints:
            with client(endpoint) as c:
                replies = c.get("fleet/@simpletrack/*/status")
            statuses = [decode_message(r, ServiceStatus) for r in replies]
            assert [s.instance for s in statuses if not isinstance(s, Rejection)] == ["env-list"], (
                endpoint
            )
    finally:
        svc.stop(signal.SIGTERM)


def test_a_list_variable_in_neither_form_names_the_variable_and_the_forms() -> None:
    out = serve("--metrics-port", "0", env={"SIMPLETRACK_ZENOH__CONNECT": "[tcp/127.0.0.1:7447"})
    assert out.returncode == 2
    line = error_line(out)
    assert line.startswith("simpletrack serve: error: SIMPLETRACK_ZENOH__CONNECT=")
    assert "'[tcp/127.0.0.1:7447'" in line
    assert "comma-separated list" in line and "JSON list" in line


def test_an_object_variable_that_is_not_json_names_the_variable() -> None:
    out = serve("--metrics-port", "0", env={"SIMPLETRACK_TRACKER": "motion=kf"})
    assert out.returncode == 2
    line = error_line(out)
    assert "SIMPLETRACK_TRACKER='motion=kf'" in line and "SIMPLETRACK_TRACKER__<FIELD>" in line


def test_a_metrics_port_in_use_is_named_with_its_address() -> None:
    with socket.socket() as busy:
        busy.bind(("127.0.0.1", 0))
        busy.listen()
        port = busy.getsockname()[1]
        out = serve(
            "--metrics-port",
            str(port),
            "--listen",
            f"tcp/127.0.0.1:{free_port()}",
            env={"SIMPLETRACK_METRICS_HOST": "127.0.0.1"},
        )
    assert out.returncode == 2
    assert error_line(out) == (
        f"simpletrack serve: error: metrics port {port} on 127.0.0.1 is in use "
        "(another simpletrack serve?): give this one --metrics-port (0: no HTTP endpoint)"
    )


def test_a_zenoh_listen_port_in_use_is_one_line_without_rust_paths() -> None:
    """The usual cause: a second serve on one host, or a Zenoh router, on the default port."""
    with socket.socket() as busy:
        busy.bind(("127.0.0.1", 0))
        busy.listen()
        endpoint = f"tcp/127.0.0.1:{busy.getsockname()[1]}"
        out = serve("--metrics-port", "0", "--listen", endpoint, env={})
    assert out.returncode == 2, out.stderr
    assert error_line(out) == (
        f"simpletrack serve: error: cannot listen on {endpoint}: the address is in use "
        "(another simpletrack service or a Zenoh router?); pass --listen with a free port"
    )
    assert ".rs:" not in out.stderr and ".cargo" not in out.stderr, out.stderr
