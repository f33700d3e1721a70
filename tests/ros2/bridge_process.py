"""A real ``simpletrack bridge ros2`` process for the tests: started with its own listening
endpoint and a connection to the service, stopped with SIGTERM (its counts on stdout)."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from dataclasses import dataclass
from pathlib import Path

from simpletrack.spawn import free_port
from tests.service_helpers import ROOT, ServiceProcess


@dataclass
class Bridge:
    proc: subprocess.Popen[bytes]
    endpoint: str
    out: Path
    err: Path

    def stderr(self) -> str:
        return self.err.read_text()

    def stop(self) -> tuple[int, str]:
        if self.proc.poll() is None:
            self.proc.send_signal(signal.SIGTERM)
        try:
            rc = self.proc.wait(30)
        except subprocess.TimeoutExpired:
            self.proc.kill()
            self.proc.wait()
            raise AssertionError(f"bridge did not stop on SIGTERM:\n{self.stderr()}") from None
        return rc, self.out.read_text()

    def kill(self) -> None:
        if self.proc.poll() is None:
            self.proc.kill()
            self.proc.wait()


def start_bridge(
    started: list[Bridge],
    tmp: Path,
    svc: ServiceProcess,
    *args: str,
    command: tuple[str, ...] = (sys.executable, "-m", "simpletrack.cli.main"),
    env: dict[str, str] | None = None,
) -> Bridge:
    """``command``: the ``simpletrack`` to run (another install's, e.g. the light one)."""
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    cmd = [
        *command, "bridge", "ros2",
        "--listen", endpoint, "--connect", svc.endpoint, "--log-interval", "0.5", *args,
    ]  # fmt: skip
    out, err = tmp / f"bridge-{len(started)}.out", tmp / f"bridge-{len(started)}.err"
    with open(out, "wb") as o, open(err, "wb") as e:
        proc = subprocess.Popen(
            cmd, cwd=ROOT, env={**(env or os.environ), "NO_COLOR": "1"}, stdout=o, stderr=e
        )
    bridge = Bridge(proc, endpoint, out, err)
    started.append(bridge)
    deadline = time.monotonic() + 60
    while "bridging " not in bridge.stderr():
        if proc.poll() is not None or time.monotonic() > deadline:
            raise AssertionError(f"bridge not up (rc {proc.poll()}):\n{bridge.stderr()}")
        time.sleep(0.05)
    return bridge
