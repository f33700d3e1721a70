"""``simpletrack view`` as a real process: the URL it prints serves, a taken port is one line."""

from __future__ import annotations

import json
import signal
import socket
import subprocess
import sys
import urllib.request

import pytest

from simpletrack.spawn import free_port
from tests.service_helpers import ROOT

pytestmark = pytest.mark.zenoh


def view_cmd(*args: str) -> list[str]:
    # Listening on a port of its own: the command does not go looking for a service.
    listen = f"tcp/127.0.0.1:{free_port()}"
    return [sys.executable, "-m", "simpletrack.cli.main", "view", "--listen", listen, *args]


def test_a_taken_http_port_is_a_one_line_error_naming_it() -> None:
    with socket.socket() as taken:
        taken.bind(("127.0.0.1", 0))
        taken.listen()
        port = taken.getsockname()[1]
        done = subprocess.run(
            view_cmd("--http-port", str(port)),
            cwd=ROOT,
            capture_output=True,
            text=True,
            timeout=60,
        )
    assert done.returncode == 2
    assert done.stderr.strip().splitlines() == [
        f"simpletrack view: error: --http-port {port} is already in use on 127.0.0.1"
    ]


def test_the_printed_url_serves_the_page_and_the_state() -> None:
    port = free_port()
    proc = subprocess.Popen(
        view_cmd("--http-port", str(port)),
        cwd=ROOT,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    try:
        assert proc.stdout is not None
        line = proc.stdout.readline()
        url = f"http://127.0.0.1:{port}/"
        assert line.startswith(f"view: {url}"), line
        with urllib.request.urlopen(url, timeout=5) as r:
            assert b"<canvas" in r.read()
        with urllib.request.urlopen(url + "state.json", timeout=5) as r:
            assert json.loads(r.read()) == {
                "detections_enabled": False,
                "sensors": {},
                "vehicles": {},
            }
    finally:
        proc.send_signal(signal.SIGTERM)
        assert proc.wait(30) == 0
