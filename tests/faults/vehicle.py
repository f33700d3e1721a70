"""What the fault tests share beyond tests/service_helpers.py: a vehicle streaming in real
time through a real ``DetectionPublisher``, a Zenoh router in a subprocess, and a service
that reaches the fleet through that router."""

from __future__ import annotations

import contextlib
import os
import signal
import socket
import subprocess
import sys
import threading
import time
from pathlib import Path

from simpletrack.client import DetectionPublisher
from simpletrack.session import ZenohOptions
from simpletrack.spawn import free_port, serve_command
from tests.service_helpers import ROOT, Received, ServiceProcess, moving_cars, wait_for

PERIOD_S = 0.1
ROUTER = """
import signal, sys, threading, zenoh
c = zenoh.Config()
c.insert_json5("mode", '"router"')
c.insert_json5("listen/endpoints", '["%s"]')
c.insert_json5("connect/endpoints", '[]')
c.insert_json5("scouting/multicast/enabled", "false")
done = threading.Event()
signal.signal(signal.SIGTERM, lambda *_: done.set())
with zenoh.open(c):
    print("router up", flush=True)
    done.wait()
"""


class RealTimeVehicle(threading.Thread):
    """Publishes three cars at 10 Hz with wall-clock stamps; where the cars are depends on
    the time, not on how many frames went out (frames lost in an outage do not slow them)."""

    def __init__(self, pub: DetectionPublisher) -> None:
        super().__init__(daemon=True)
        self.pub = pub
        self.t0 = time.monotonic()
        self.stop_event = threading.Event()

    def run(self) -> None:
        while not self.stop_event.wait(PERIOD_S):
            k = round((time.monotonic() - self.t0) / PERIOD_S)
            with contextlib.suppress(Exception):  # a put during an outage may fail: go on
                self.pub.publish(moving_cars(k))

    def stop(self) -> None:
        self.stop_event.set()
        self.join(5)
        self.pub.close()


def ids_since(received: Received, sensor: str, t_ns: int) -> list[list[int]]:
    """Sorted track ids of every frame of ``sensor`` the service received after ``t_ns``."""
    with received.lock:
        frames = list(received.tracks.get(sensor, []))
    return [sorted(t.id.tolist()) for f, t in frames if f.received_ns > t_ns]


def last_ids(received: Received, sensor: str) -> list[int]:
    with received.lock:
        return sorted(received.tracks[sensor][-1][1].id.tolist())


def _port_open(port: int) -> bool:
    with socket.socket() as s:
        s.settimeout(0.2)
        return s.connect_ex(("127.0.0.1", port)) == 0


def start_router(port: int) -> subprocess.Popen[bytes]:
    """A Zenoh router (a Python session in router mode) on 127.0.0.1:``port``."""
    code = ROUTER % f"tcp/127.0.0.1:{port}"
    proc = subprocess.Popen([sys.executable, "-c", code], stdout=subprocess.PIPE)
    wait_for(lambda: _port_open(port), 30, f"a router on port {port}")
    return proc


def start_service_via_router(tmp: Path, router: str, *args: str) -> ServiceProcess:
    """``simpletrack serve`` in client mode, connected to ``router`` (which must be up)."""
    metrics_port = free_port()
    instance = "svc-routed"
    cmd = serve_command("unused", metrics_port, instance, "--mode", "client", *args)
    i = cmd.index("--listen")
    del cmd[i : i + 2]  # a client does not listen
    cmd += ["--connect", router]
    log_path = tmp / f"{instance}.log"
    env = {**os.environ, "SIMPLETRACK_LOG_FORMAT": "json", "NO_COLOR": "1"}
    with open(log_path, "wb") as log:
        proc = subprocess.Popen(cmd, cwd=ROOT, env=env, stdout=log, stderr=log)
    svc = ServiceProcess(proc, router, metrics_port, log_path, instance)
    deadline = time.monotonic() + 60
    while True:
        if proc.poll() is not None:
            raise AssertionError(f"service exited:\n{log_path.read_text()}")
        with contextlib.suppress(OSError):
            if svc.http("/readyz")[0] == 200:
                return svc
        if time.monotonic() > deadline:
            svc.stop(signal.SIGKILL)
            raise AssertionError(f"service not ready:\n{log_path.read_text()}")
        time.sleep(0.05)


def vehicle_options(endpoint: str, mode: str = "peer") -> ZenohOptions:
    if mode == "client":
        return ZenohOptions(mode="client", connect=[endpoint], connect_timeout_ms=-1)
    return ZenohOptions(connect=[endpoint])
