"""Track a recorded sequence through a real service over Zenoh (what ``eval --transport zenoh``
uses): the same frames in, the same ``Tracks`` out as ``Tracker.step`` in-process, up to the
float32 rounding of the wire.

    with spawn_service("kitti") as endpoint:
        outputs = track_sequence_over_zenoh(frames, config, connect=endpoint, sensor="0003")
"""

from __future__ import annotations

import contextlib
import os
import socket
import subprocess
import sys
import tempfile
import threading
import time
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import IO

import zenoh

from simpletrack.core.config import TrackerConfig
from simpletrack.core.frames import Frame, Tracks
from simpletrack.server.settings import config_digest
from simpletrack.session import ZenohOptions, open_session
from simpletrack.wire.codec import (
    Rejection,
    decode_message,
    decode_track_frame,
    encode_detection_frame,
)
from simpletrack.wire.convert import boxes_to_wire, tracks_from_wire
from simpletrack.wire.keys import Keys
from simpletrack.wire.models import FrameError, ServiceStatus

ROOT = Path(__file__).resolve().parents[3]
STAMP_ORIGIN_NS = 1_000_000_000  # frame stamps (seconds) are sent as origin + stamp * 1e9


class RemoteError(RuntimeError):
    """The service refused a frame, or did not answer in time."""


def track_sequence_over_zenoh(
    frames: Sequence[Frame],
    config: TrackerConfig,
    *,
    connect: str,
    sensor: str = "seq",
    vehicle: str | None = None,
    prefix: str = "fleet",
    window: int = 16,
    timeout_s: float = 30.0,
) -> list[Tracks]:
    """Send ``frames`` (stamps in seconds, increasing) as one sensor stream to the service at
    ``connect`` and return its tracks for every frame, in order. At most ``window`` frames are
    in flight, so a default ``drop_oldest`` service never sheds any. Raises ``RemoteError``
    if the service runs another tracker configuration, refuses a frame, or goes silent."""
    keys = Keys(prefix)
    vehicle = vehicle or f"eval-{os.getpid()}-{time.monotonic_ns() % 10**9}"
    results: dict[int, Tracks | FrameError] = {}
    cond = threading.Condition()

    def on_tracks(sample: zenoh.Sample) -> None:
        out = decode_track_frame(sample.payload.to_bytes())
        if isinstance(out, Rejection):
            return
        with cond:
            results[out[0].seq] = tracks_from_wire(out[1])
            cond.notify_all()

    def on_error(sample: zenoh.Sample) -> None:
        err = decode_message(sample.payload.to_bytes(), FrameError)
        if isinstance(err, Rejection) or err.seq is None:
            return
        with cond:
            results[err.seq] = err
            cond.notify_all()

    with open_session(ZenohOptions(connect=[connect])) as session:
        _check_config(session, keys, config, timeout_s)
        session.declare_subscriber(keys.tracks(vehicle, sensor), on_tracks)
        session.declare_subscriber(keys.errors(vehicle, sensor), on_error)
        pub = session.declare_publisher(
            keys.detections(vehicle, sensor), congestion_control=zenoh.CongestionControl.BLOCK
        )
        # The stub says bool; at runtime it is a MatchingStatus.
        _wait(
            lambda: bool(pub.matching_status.matching),  # type: ignore[attr-defined]
            timeout_s,
            "the service's subscriber",
        )
        time.sleep(0.05)  # let our own subscriptions reach the service
        classes = config.class_names
        for k, frame in enumerate(frames):
            in_flight_ok = _room(results, k, window)
            with cond:
                if not cond.wait_for(in_flight_ok, timeout_s):
                    raise RemoteError(f"no tracks from the service for {timeout_s}s (frame {k})")
            pub.put(
                encode_detection_frame(
                    vehicle=vehicle,
                    sensor=sensor,
                    seq=k,
                    stamp_ns=STAMP_ORIGIN_NS + round(frame.stamp * 1e9),
                    frame_id="sensor",
                    boxes=boxes_to_wire(frame.boxes, classes),
                    pose=frame.pose,
                    key_frame=frame.key_frame,
                )
            )
        with cond:
            if not cond.wait_for(lambda: len(results) == len(frames), timeout_s):
                raise RemoteError(f"the service answered {len(results)} of {len(frames)} frames")
    out = []
    for k in range(len(frames)):
        r = results[k]
        if isinstance(r, FrameError):
            raise RemoteError(f"the service refused frame {k}: {r.reason.value} ({r.detail})")
        out.append(r)
    return out


def _room(results: dict[int, Tracks | FrameError], k: int, window: int) -> Callable[[], bool]:
    return lambda: k - len(results) < window


def _check_config(
    session: zenoh.Session, keys: Keys, config: TrackerConfig, timeout_s: float
) -> None:
    deadline = time.monotonic() + timeout_s
    while True:
        replies = list(session.get(keys.status(), timeout=2.0))
        statuses = [decode_message(r.ok.payload.to_bytes(), ServiceStatus) for r in replies if r.ok]
        good = [s for s in statuses if not isinstance(s, Rejection)]
        if good:
            break
        if time.monotonic() > deadline:
            raise RemoteError("no service answered its status query")
        time.sleep(0.1)
    want = config_digest(config)
    if all(s.config_digest != want for s in good):
        raise RemoteError(
            "the service runs another tracker configuration "
            f"(preset {', '.join(s.preset for s in good)}); start it with the same preset"
        )


def _wait(pred: Callable[[], bool], timeout_s: float, what: str) -> None:
    deadline = time.monotonic() + timeout_s
    while not pred():
        if time.monotonic() > deadline:
            raise RemoteError(f"timed out waiting for {what}")
        time.sleep(0.01)


def free_port() -> int:
    """A TCP port free on 127.0.0.1 right now."""
    return free_run(1)


def free_run(n: int) -> int:
    """A port p such that p .. p+n-1 are free on 127.0.0.1 right now.

    The ports come from below the kernel's ephemeral range: a port the kernel handed out
    (bind to 0) and we released can be taken again as the source port of any outgoing
    connection before our listener binds it (a CI run failed with "Address already in use"
    that way). Each process starts at its own offset and never hands a port out twice."""
    lo, span = _PORT_POOL
    for _ in range(span):
        with _PORT_LOCK:
            offset = _port_cursor[0] % (span - n)
            _port_cursor[0] = offset + n
        base = lo + offset
        if all(_bindable(p) for p in range(base, base + n)):
            return base
    raise RuntimeError(f"no {n} consecutive free ports in {lo}..{lo + span - 1}")


def _bindable(port: int) -> bool:
    with socket.socket() as s:
        try:
            s.bind(("127.0.0.1", port))
        except OSError:
            return False
    return True


def _port_pool() -> tuple[int, int]:
    """(first port, count) of the ports below the ephemeral range, from 10000."""
    try:
        text = Path("/proc/sys/net/ipv4/ip_local_port_range").read_text()
        ephemeral_lo = int(text.split()[0])
    except (OSError, ValueError, IndexError):
        ephemeral_lo = 32768
    if ephemeral_lo - 10000 < 1000:  # an unusual range: take the ports above it instead
        return 61000, 4000
    return 10000, ephemeral_lo - 10000


_PORT_POOL = _port_pool()
_PORT_LOCK = threading.Lock()
_port_cursor = [(os.getpid() * 7919) % _PORT_POOL[1]]  # each process starts elsewhere


def serve_command(endpoint: str, metrics_port: int, instance: str, *extra: str) -> list[str]:
    """``simpletrack serve`` with this interpreter, listening on ``endpoint`` only."""
    return [
        sys.executable,
        "-m",
        "simpletrack.cli.main",
        "serve",
        "--listen",
        endpoint,
        "--metrics-port",
        str(metrics_port),
        "--instance",
        instance,
        *extra,
    ]


def _port_open(endpoint: str) -> bool:
    host, _, port = endpoint.removeprefix("tcp/").rpartition(":")
    with socket.socket() as s:
        s.settimeout(0.2)
        return s.connect_ex((host, int(port))) == 0


@dataclass(frozen=True)
class SpawnedService:
    endpoint: str
    instance: str
    proc: subprocess.Popen[bytes]


@contextlib.contextmanager
def spawned_service(
    preset: str, *extra: str, log: IO[bytes], startup_s: float = 60.0
) -> Iterator[SpawnedService]:
    """Run ``simpletrack serve --preset PRESET`` on a free loopback port for the duration of
    the block (lossless backpressure, no metrics port, no state directory), its output in
    ``log``. Stopped with SIGTERM; a service that died on its own is left as it is."""
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    instance = f"eval-{os.getpid()}"
    cmd = serve_command(
        endpoint,
        0,
        instance,
        "--preset",
        preset,
        "--backpressure",
        "block",
        "--log-level",
        "warning",
        *extra,
    )
    proc = subprocess.Popen(cmd, cwd=ROOT, stdout=log, stderr=log)
    try:
        deadline = time.monotonic() + startup_s
        while not _port_open(endpoint):
            if proc.poll() is not None:
                log.seek(0)
                tail = log.read().decode(errors="replace").strip()[-500:]
                raise RemoteError(f"the service exited ({proc.returncode}): {tail}")
            if time.monotonic() > deadline:
                raise RemoteError("the service did not start in time")
            time.sleep(0.05)
        with open_session(ZenohOptions(connect=[endpoint])) as session:
            _check_started(session, Keys().status(instance), deadline)
        yield SpawnedService(endpoint, instance, proc)
    finally:
        if proc.poll() is None:
            proc.terminate()
            try:
                proc.wait(30)
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.wait()


@contextlib.contextmanager
def spawn_service(preset: str, *extra: str, startup_s: float = 60.0) -> Iterator[str]:
    """``spawned_service`` with its output thrown away; yields the endpoint."""
    with (
        tempfile.TemporaryFile() as log,
        spawned_service(preset, *extra, log=log, startup_s=startup_s) as svc,
    ):
        yield svc.endpoint


def _check_started(session: zenoh.Session, status_key: str, deadline: float) -> None:
    while not [r for r in session.get(status_key, timeout=1.0) if r.ok]:
        if time.monotonic() > deadline:
            raise RemoteError("the service did not answer its status query in time")
        time.sleep(0.05)
