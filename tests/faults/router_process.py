"""A Zenoh router in a subprocess (a Python session in router mode) and a service that is a
client of it, for the fault tests: kill the router with a real signal, start it again on the
same port."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path

from simpletrack.spawn import free_port
from tests.service_helpers import ROOT, ServiceProcess

ROUTER_CODE = """
import json, signal, sys, threading, zenoh
c = zenoh.Config()
c.insert_json5("mode", '"router"')
c.insert_json5("listen/endpoints", '["%s"]' % sys.argv[1])
c.insert_json5("connect/endpoints", "[]")
c.insert_json5("scouting/multicast/enabled", "false")
for key, value in json.loads(sys.argv[2]).items():
    c.insert_json5(key, json.dumps(value))
session = zenoh.open(c)
stop = threading.Event()
signal.signal(signal.SIGTERM, lambda *_: stop.set())
print("up", flush=True)
stop.wait()
session.close()
"""


@dataclass
class Router:
    endpoint: str
    proc: subprocess.Popen[bytes] | None = None
    config: dict[str, object] = field(default_factory=dict)  # Zenoh config key -> value

    def start(self, timeout: float = 30.0) -> Router:
        assert self.proc is None or self.proc.poll() is not None, "router already running"
        self.proc = subprocess.Popen(
            [sys.executable, "-c", ROUTER_CODE, self.endpoint, json.dumps(self.config)],
            stdout=subprocess.PIPE,
            stderr=subprocess.DEVNULL,
        )
        assert self.proc.stdout is not None
        deadline = time.monotonic() + timeout
        line = self.proc.stdout.readline()  # "up" once it listens; EOF if it died
        if line.strip() != b"up" or time.monotonic() > deadline:
            raise AssertionError(f"router on {self.endpoint} did not come up")
        return self

    def kill(self) -> None:
        """SIGKILL: the router vanishes without closing anything."""
        assert self.proc is not None
        self.proc.send_signal(signal.SIGKILL)
        self.proc.wait(10)

    def stop(self) -> None:
        if self.proc is not None and self.proc.poll() is None:
            self.proc.terminate()
            try:
                self.proc.wait(10)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait()


def new_router(config: dict[str, object] | None = None) -> Router:
    return Router(f"tcp/127.0.0.1:{free_port()}", config=config or {})


def start_client_service(
    tmp: Path, router: str, *args: str, env: dict[str, str] | None = None, instance: str = "svc"
) -> ServiceProcess:
    """``simpletrack serve --mode client --connect ROUTER``, not waited for (it may have
    no router yet): wait for /readyz yourself."""
    metrics_port = free_port()
    log_path = tmp / f"{instance}-{metrics_port}.log"
    cmd = [
        sys.executable,
        "-m",
        "simpletrack.cli.main",
        "serve",
        "--mode",
        "client",
        "--connect",
        router,
        "--metrics-port",
        str(metrics_port),
        "--instance",
        instance,
        *args,
    ]
    full_env = {**os.environ, "SIMPLETRACK_LOG_FORMAT": "json", "NO_COLOR": "1", **(env or {})}
    with open(log_path, "wb") as log:
        proc = subprocess.Popen(cmd, cwd=ROOT, env=full_env, stdout=log, stderr=log)
    svc = ServiceProcess(proc, router, metrics_port, log_path, instance)
    deadline = time.monotonic() + 60
    while True:  # the HTTP endpoint comes first, before any Zenoh session
        if proc.poll() is not None:
            return svc
        try:
            svc.http("/healthz")
            return svc
        except OSError:
            pass
        if time.monotonic() > deadline:
            svc.stop(signal.SIGKILL)
            raise AssertionError(f"service never served /healthz:\n{log_path.read_text()}")
        time.sleep(0.05)
