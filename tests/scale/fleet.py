"""What the scale-out tests share: a group of ``simpletrack serve`` processes on one prefix, a
fleet replaying real KITTI detections at 10 Hz in real time, a planner recording every
tracks message, and the tracks a single uninterrupted tracker gives on the same frames."""

from __future__ import annotations

import contextlib
import threading
import time
from collections import Counter
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pytest
import zenoh

from simpletrack.client import DetectionPublisher
from simpletrack.core.tracker import Tracker
from simpletrack.datasets.kitti import load_sequence
from simpletrack.server.settings import ServiceSettings
from simpletrack.session import open_session
from simpletrack.spawn import free_port
from simpletrack.wire import BoxArrays, Rejection, TrackArrays, TrackFrame, decode_track_frame
from simpletrack.wire.codec import decode_detection_frame, encode_detection_frame
from simpletrack.wire.convert import boxes_to_wire, frame_from_wire, tracks_to_wire
from tests.faults.router_process import start_client_service
from tests.service_helpers import DATA, ServiceProcess, start_service, wait_for

KITTI = DATA / "kitti"
PERIOD_S = 0.1
CLASSES = ("Car", "Pedestrian", "Cyclist")
T0_NS = 1_700_000_000_000_000_000

needs_kitti = pytest.mark.skipif(
    not (KITTI / "detections").is_dir(), reason=f"KITTI data not found under {KITTI}"
)


def sequences() -> list[str]:
    return sorted(p.stem for p in (KITTI / "labels").glob("*.txt"))


def fleet_frames(n_sensors: int, n_frames: int) -> dict[str, list[BoxArrays]]:
    """Per sensor ``car-<i>/lidar``: the first ``n_frames`` of KITTI sequence i % 10."""
    config = ServiceSettings(group=False).tracker_config()
    seqs = sequences()
    cache: dict[str, list[BoxArrays]] = {}
    out: dict[str, list[BoxArrays]] = {}
    for i in range(n_sensors):
        seq = seqs[i % len(seqs)]
        if seq not in cache:
            frames = load_sequence(KITTI, seq, config, CLASSES)[:n_frames]
            cache[seq] = [boxes_to_wire(f.boxes, config.class_names) for f in frames]
        out[f"car-{i}/lidar"] = cache[seq]
    return out


def stamp_of(k: int) -> int:
    return T0_NS + k * 100_000_000


def expected_tracks(name: str, frames: list[BoxArrays]) -> list[TrackArrays]:
    """What one uninterrupted instance answers to these frames (the worker's own path)."""
    config = ServiceSettings(group=False).tracker_config()
    codes = {n: code for code, n in enumerate(config.class_names)}
    tracker = Tracker(config)
    vehicle, sensor = name.split("/")
    out = []
    for k, boxes in enumerate(frames):
        payload = encode_detection_frame(
            vehicle=vehicle,
            sensor=sensor,
            seq=k,
            stamp_ns=stamp_of(k),
            frame_id=sensor,
            boxes=boxes,
        )
        decoded = decode_detection_frame(payload, class_codes=codes)
        assert not isinstance(decoded, Rejection), decoded
        frame, _ = frame_from_wire(decoded, (stamp_of(k) - T0_NS) * 1e-9)
        out.append(tracks_to_wire(tracker.step(frame), 0, config.class_names))
    return out


@dataclass
class Planner:
    """Every tracks message of the fleet, as it arrived."""

    frames: dict[str, list[tuple[TrackFrame, TrackArrays]]] = field(default_factory=dict)
    lock: threading.Lock = field(default_factory=threading.Lock)

    def on_tracks(self, sample: zenoh.Sample) -> None:
        out = decode_track_frame(sample.payload.to_bytes())
        assert not isinstance(out, Rejection), out
        with self.lock:
            self.frames.setdefault(f"{out[0].vehicle}/{out[0].sensor}", []).append(out)

    def count(self) -> int:
        with self.lock:
            return sum(len(v) for v in self.frames.values())

    def instances(self, since_ns: int = 0) -> Counter[str]:
        with self.lock:
            return Counter(
                f.instance for v in self.frames.values() for f, _ in v if f.published_ns > since_ns
            )


class Fleet(threading.Thread):
    """Sensors replaying their frames at 10 Hz, stamps ``T0 + k * 100 ms`` (the stamps a
    vehicle's clock gives, whatever the machine's load): one session, one advanced publisher
    (with its cache) per sensor."""

    def __init__(
        self, session: zenoh.Session, frames: dict[str, list[BoxArrays]], cache_frames: int = 100
    ) -> None:
        super().__init__(daemon=True)
        self.frames = frames
        self.pubs = {
            name: DetectionPublisher(
                session, *name.split("/"), classes=CLASSES, cache_frames=cache_frames
            )
            for name in frames
        }
        self.sent: dict[str, int] = dict.fromkeys(frames, 0)
        self.n = min(len(v) for v in frames.values())
        self.k = -1  # the last frame index sent
        self.done = threading.Event()
        self._halt = threading.Event()

    def wait_for_service(self, timeout: float) -> bool:
        return all(p.wait_for_service(timeout) for p in self.pubs.values())

    def run(self) -> None:
        t0 = time.monotonic()
        for k in range(self.n):
            delay = t0 + k * PERIOD_S - time.monotonic()
            if self._halt.wait(max(0.0, delay)):
                break
            for name, pub in self.pubs.items():
                pub.publish_arrays(self.frames[name][k], stamp_ns=stamp_of(k))
                self.sent[name] += 1
            self.k = k
        self.done.set()

    def close(self) -> None:
        self._halt.set()
        self.join(10)
        for p in self.pubs.values():
            with contextlib.suppress(Exception):
                p.close()


@dataclass
class Group:
    """Members in peer mode, each listening on its own port and connected to the others;
    or, with ``router``, clients of that router process."""

    tmp: Path
    args: tuple[str, ...] = ()
    router: str | None = None
    state: bool = False  # each member its own --state-dir, kept across its restarts
    # Room for 3 s of frames: on 2 shared cores a member starting (imports) stalls the
    # others that long, and a full queue drops (announced, but not what these tests test).
    env: dict[str, str] = field(default_factory=lambda: {"SIMPLETRACK_QUEUE_SIZE": "1000"})
    members: dict[str, ServiceProcess] = field(default_factory=dict)
    ports: dict[str, int] = field(default_factory=dict)

    def endpoints(self) -> list[str]:
        if self.router is not None:
            return [self.router]
        return [f"tcp/127.0.0.1:{p}" for p in self.ports.values()]

    def add(self, name: str, env: dict[str, str] | None = None) -> ServiceProcess:
        env = {**self.env, **(env or {})}
        args = self.args
        if self.state:
            args = (*args, "--state-dir", str(self.tmp / "state" / name))
        if self.router is not None:
            svc = start_client_service(self.tmp, self.router, *args, env=env, instance=name)
            wait_for(lambda: svc.http("/readyz")[0] == 200, 30, f"{name} ready")
            self.members[name] = svc
            return svc
        port = free_port()
        connect = [a for e in self.endpoints() for a in ("--connect", e)]
        svc = start_service(self.tmp, *connect, *args, env=env, port=port, instance=name)
        self.members[name], self.ports[name] = svc, port
        return svc

    def remove(self, name: str) -> ServiceProcess:
        self.ports.pop(name, None)
        return self.members.pop(name)

    def stop_all(self) -> None:
        for svc in self.members.values():
            with contextlib.suppress(Exception):
                svc.stop()


def planner_session(group: Group) -> zenoh.Session:
    mode = "client" if group.router is not None else "peer"
    return open_session(mode=mode, connect=group.endpoints())


def mismatches(
    planner: Planner, frames: dict[str, list[BoxArrays]], n_frames: int
) -> tuple[list[str], list[str], int]:
    """(frames not answered exactly once, tracks unequal to the reference, repeats). A
    repeat is the one allowed exception: a failover publishes the dead member's last frame
    again (its put may have reached only some links), so a frame answered by one member and
    then once more by another is counted as a repeat, and its tracks must equal too."""
    counts, unequal, repeats = [], [], 0
    with planner.lock:
        got = {k: list(v) for k, v in planner.frames.items()}
    for name, payloads in frames.items():
        expected = expected_tracks(name, payloads[:n_frames])
        by_seq: dict[int, list[tuple[TrackFrame, TrackArrays]]] = {}
        for f, t in got.get(name, []):
            by_seq.setdefault(f.seq, []).append((f, t))
        for seq in range(n_frames):
            answers = by_seq.get(seq, [])
            republished = len(answers) == 2 and answers[0][0].instance != answers[1][0].instance
            if len(answers) != 1 and not republished:
                counts.append(f"{name} seq {seq}: {len(answers)} tracks messages")
                continue
            repeats += republished
            e = expected[seq]
            for _, a in answers:
                if not same_tracks(a, e):
                    unequal.append(f"{name} seq {seq}: ids {sorted(a.id)} vs {sorted(e.id)}")
    return counts, unequal, repeats


def same_tracks(a: TrackArrays, e: TrackArrays) -> bool:
    """The same ids, and each at the same place (to float32 rounding)."""
    return (
        a.id.shape == e.id.shape
        and np.array_equal(np.sort(a.id), np.sort(e.id))
        and np.allclose(a.center[np.argsort(a.id)], e.center[np.argsort(e.id)], atol=1e-4)
    )
