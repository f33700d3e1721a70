"""Run ``simpletrack serve`` in a subprocess and talk to it over real Zenoh on 127.0.0.1.

The test process opens its own Zenoh session (never fork after that: the service is started
with subprocess, i.e. fork+exec, before or after, which is safe) and connects it to the
service's listen endpoint; multicast scouting is off on both sides.
"""

from __future__ import annotations

import contextlib
import json
import logging
import os
import signal
import subprocess
import threading
import time
import urllib.error
import urllib.request
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import zenoh

from simpletrack.session import open_session
from simpletrack.spawn import free_port, serve_command
from simpletrack.wire import (
    BoxArrays,
    FrameError,
    Rejection,
    TrackArrays,
    TrackFrame,
    decode_message,
    decode_track_frame,
    encode_detection_frame,
)
from simpletrack.wire.keys import Keys

ROOT = Path(__file__).resolve().parents[1]
DATA = ROOT.parent / "shared" / "data"


class LogEvents(logging.Handler):
    """What one of the service's loggers logged: (event, level, fields) per line."""

    def __init__(self) -> None:
        super().__init__(logging.DEBUG)
        self.events: list[tuple[str, int, dict[str, Any]]] = []

    def emit(self, record: logging.LogRecord) -> None:
        self.events.append((record.getMessage(), record.levelno, getattr(record, "fields", {})))

    def named(self, event: str) -> list[dict[str, Any]]:
        return [f for e, _, f in self.events if e == event]


@contextlib.contextmanager
def log_events(name: str) -> Iterator[LogEvents]:
    """Every line the logger ``name`` logs (DEBUG up) while the block runs."""
    logger = logging.getLogger(name)
    handler, level = LogEvents(), logger.level
    logger.addHandler(handler)
    logger.setLevel(logging.DEBUG)
    try:
        yield handler
    finally:
        logger.removeHandler(handler)
        logger.setLevel(level)


def wait_for(pred: Callable[[], bool], timeout: float, what: str = "condition") -> None:
    deadline = time.monotonic() + timeout
    while not pred():
        if time.monotonic() > deadline:
            raise AssertionError(f"timed out after {timeout}s waiting for {what}")
        time.sleep(0.01)


@dataclass
class ServiceProcess:
    """A running ``simpletrack serve``; ``stop()`` sends SIGTERM and waits."""

    proc: subprocess.Popen[bytes]
    endpoint: str
    metrics_port: int
    log_path: Path
    instance: str

    def threads(self) -> int:
        """The process's threads now (Linux)."""
        return len(os.listdir(f"/proc/{self.proc.pid}/task"))

    def logs(self) -> list[dict[str, Any]]:
        out = []
        for line in self.log_path.read_text().splitlines():
            with contextlib.suppress(json.JSONDecodeError):
                out.append(json.loads(line))
        return out

    def http(self, path: str) -> tuple[int, str]:
        try:
            with urllib.request.urlopen(
                f"http://127.0.0.1:{self.metrics_port}{path}", timeout=5
            ) as r:
                return int(r.status), r.read().decode()
        except urllib.error.HTTPError as e:
            return int(e.code), e.read().decode()

    def metrics(self) -> dict[str, float]:
        """Every sample of /metrics as ``name{labels}`` -> value."""
        _, text = self.http("/metrics")
        out = {}
        for line in text.splitlines():
            if line and not line.startswith("#"):
                name, _, value = line.rpartition(" ")
                out[name] = float(value)
        return out

    def stop(self, sig: int = signal.SIGTERM, timeout: float = 30.0) -> int:
        if self.proc.poll() is None:
            self.proc.send_signal(sig)
        try:
            return self.proc.wait(timeout)
        except subprocess.TimeoutExpired:
            self.proc.kill()
            self.proc.wait()
            raise AssertionError(
                f"service did not exit after {sig!r}:\n{self.log_path.read_text()}"
            ) from None


def start_service(
    tmp: Path,
    *args: str,
    env: dict[str, str] | None = None,
    port: int | None = None,
    instance: str = "svc-test",
) -> ServiceProcess:
    port = port or free_port()
    metrics_port = free_port()
    endpoint = f"tcp/127.0.0.1:{port}"
    log_path = tmp / f"{instance}-{port}.log"
    cmd = serve_command(endpoint, metrics_port, instance, *args)
    full_env = {**os.environ, "SIMPLETRACK_LOG_FORMAT": "json", "NO_COLOR": "1", **(env or {})}
    with open(log_path, "wb") as log:
        proc = subprocess.Popen(cmd, cwd=ROOT, env=full_env, stdout=log, stderr=log)
    svc = ServiceProcess(proc, endpoint, metrics_port, log_path, instance)
    deadline = time.monotonic() + 60
    while True:
        if proc.poll() is not None:
            raise AssertionError(f"service exited with {proc.returncode}:\n{log_path.read_text()}")
        with contextlib.suppress(OSError):
            if svc.http("/readyz")[0] == 200:
                return svc
        if time.monotonic() > deadline:
            svc.stop(signal.SIGKILL)
            raise AssertionError(f"service not ready:\n{log_path.read_text()}")
        time.sleep(0.05)


@dataclass
class Received:
    """Everything a planner-side subscriber saw, per sensor, in arrival order."""

    tracks: dict[str, list[tuple[TrackFrame, TrackArrays]]] = field(default_factory=dict)
    errors: dict[str, list[FrameError]] = field(default_factory=dict)
    lock: threading.Lock = field(default_factory=threading.Lock)

    def on_tracks(self, sample: zenoh.Sample) -> None:
        out = decode_track_frame(sample.payload.to_bytes())
        assert not isinstance(out, Rejection), out
        with self.lock:
            self.tracks.setdefault(f"{out[0].vehicle}/{out[0].sensor}", []).append(out)

    def on_errors(self, sample: zenoh.Sample) -> None:
        err = decode_message(sample.payload.to_bytes(), FrameError)
        assert not isinstance(err, Rejection), err
        with self.lock:
            self.errors.setdefault(f"{err.vehicle}/{err.sensor}", []).append(err)

    def n_tracks(self, sensor: str) -> int:
        with self.lock:
            return len(self.tracks.get(sensor, []))

    def n_errors(self, sensor: str) -> int:
        with self.lock:
            return len(self.errors.get(sensor, []))


class Client:
    """The test's side: a vehicle publisher and a planner subscriber in one Zenoh session."""

    def __init__(self, endpoint: str, prefix: str = "fleet") -> None:
        self.keys = Keys(prefix)
        self.session = open_session(mode="peer", connect=[endpoint])
        self.received = Received()
        self._subs = [
            self.session.declare_subscriber(f"{prefix}/*/*/tracks", self.received.on_tracks),
            self.session.declare_subscriber(f"{prefix}/*/*/errors", self.received.on_errors),
        ]
        self._pubs: dict[str, zenoh.Publisher] = {}

    def publisher(self, vehicle: str, sensor: str) -> zenoh.Publisher:
        key = self.keys.detections(vehicle, sensor)
        if key not in self._pubs:
            pub = self.session.declare_publisher(
                key, congestion_control=zenoh.CongestionControl.BLOCK
            )
            wait_for(lambda: pub.matching_status.matching, 10, f"a subscriber on {key}")
            self._pubs[key] = pub
        return self._pubs[key]

    def put(self, vehicle: str, sensor: str, payload: bytes) -> None:
        self.publisher(vehicle, sensor).put(payload)

    def send(
        self, vehicle: str, sensor: str, seq: int, stamp_ns: int, boxes: BoxArrays, **kw: Any
    ) -> None:
        self.put(
            vehicle,
            sensor,
            encode_detection_frame(
                vehicle=vehicle,
                sensor=sensor,
                seq=seq,
                stamp_ns=stamp_ns,
                frame_id=kw.pop("frame_id", "lidar"),
                boxes=boxes,
                **kw,
            ),
        )

    def get(self, selector: str, timeout: float = 5.0) -> list[bytes]:
        return [
            r.ok.payload.to_bytes() for r in self.session.get(selector, timeout=timeout) if r.ok
        ]

    def close(self) -> None:
        self.session.close()  # type: ignore[no-untyped-call]


@contextlib.contextmanager
def client(endpoint: str) -> Iterator[Client]:
    c = Client(endpoint)
    try:
        yield c
    finally:
        c.close()


def moving_cars(k: int, n: int = 3, classes: tuple[str, ...] = ("Car",)) -> BoxArrays:
    """Frame k of n cars 10 m apart driving along +x at 10 m/s (10 Hz): easy to track."""
    i = np.arange(n, dtype=np.float32)
    center = np.stack([10.0 + k * 1.0 + 0 * i, 10.0 * i, 0.8 + 0 * i], axis=1)
    return BoxArrays(
        classes=classes,
        class_index=np.zeros(n, np.int32),
        center=center.astype(np.float32),
        size=np.tile(np.float32([4.0, 1.8, 1.6]), (n, 1)),
        yaw=np.zeros(n, np.float32),
        score=np.full(n, 0.9, np.float32),
    )


def stamp(k: int, period_ns: int = 100_000_000, t0: int = 1_700_000_000_000_000_000) -> int:
    return t0 + k * period_ns


def metric(values: dict[str, float], name: str, **labels: str) -> float:
    if labels:
        inner = ",".join(f'{k}="{v}"' for k, v in labels.items())
        return values.get(f"{name}{{{inner}}}", 0.0)
    return values.get(name, 0.0)
