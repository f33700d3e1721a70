"""A rolling upgrade from the version before fusion (83a030f) to this one: a member of each
on one prefix, a vehicle whose lidar and camera the new member's settings fuse. While the old
member is in the group, every sensor is its own stream for both (the new member's fusion
waits for every member to hold the fusion token): each frame is answered exactly once, on its
sensor's tracks key, none on the vehicle's. Once the old member is gone, the new one fuses:
the vehicle's frames are answered on ``<vehicle>/@vehicle/tracks``. No sensor is owned twice
or by nobody at any point (server/streams.py)."""

from __future__ import annotations

import contextlib
import os
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest
import zenoh

from simpletrack.bench.against import AgainstError, ref_tree, resolve
from simpletrack.client import DetectionPublisher
from simpletrack.session import open_session
from simpletrack.spawn import free_port
from simpletrack.wire import Rejection, decode_track_frame, decode_vehicle_track_frame
from tests.core.fusion_helpers import crossing, mount, schedule
from tests.fusion_scenario import CLASSES, write_config
from tests.service_helpers import ROOT, ServiceProcess, start_service, wait_for

pytestmark = pytest.mark.zenoh
OLD = "83a030f"
SECONDS = 6.0
UPGRADE_AT = 2.5  # seconds of frames sent before the old member stops


def _old_tree(tmp: Path) -> contextlib.AbstractContextManager[Path]:
    try:
        revision = resolve(ROOT, OLD)
    except AgainstError as e:
        pytest.skip(f"the version before fusion is not in this checkout: {e}")
    return ref_tree(ROOT, revision, tmp)


def _start_old(tree: Path, tmp: Path) -> ServiceProcess:
    port, metrics = free_port(), free_port()
    endpoint = f"tcp/127.0.0.1:{port}"
    log = tmp / "m-old.log"
    env = {
        **os.environ,
        "PYTHONPATH": os.pathsep.join(str(tree / f) for f in ("service", "schemas", "clients")),
        "SIMPLETRACK_JIT": "0",  # its kernels would compile for a minute: run them as Python
        "SIMPLETRACK_LOG_FORMAT": "json",
    }
    cmd = [sys.executable, "-P", "-m", "simpletrack.cli.main", "serve", "--listen", endpoint,
           "--metrics-port", str(metrics), "--instance", "m-old"]  # fmt: skip
    with open(log, "wb") as f:
        proc = subprocess.Popen(cmd, env=env, stdout=f, stderr=f)
    svc = ServiceProcess(proc, endpoint, metrics, log, "m-old")
    wait_for(lambda: _ready(svc), 120, "the old member ready")
    return svc


def _ready(svc: ServiceProcess) -> bool:
    if svc.proc.poll() is not None:
        raise AssertionError(f"the old member exited:\n{svc.log_path.read_text()[-3000:]}")
    with contextlib.suppress(OSError):
        return svc.http("/readyz")[0] == 200
    return False


def test_a_rolling_upgrade_to_fusion_owns_every_sensor_once(tmp_path: Path) -> None:
    config = write_config(tmp_path)
    world = crossing()
    with _old_tree(tmp_path) as tree:
        old = _start_old(tree, tmp_path)
        new = start_service(
            tmp_path, "--connect", old.endpoint, "--config", str(config), instance="m-new"
        )
        try:
            session = open_session(mode="peer", connect=[old.endpoint, new.endpoint])
            sensor_answers: dict[tuple[str, int], list[str]] = {}
            fused: list[tuple[int, str, int]] = []  # (stamp, sensor, its seq)
            lock = threading.Lock()

            def on_tracks(sample: zenoh.Sample) -> None:
                out = decode_track_frame(sample.payload.to_bytes())
                assert not isinstance(out, Rejection), out
                with lock:
                    sensor_answers.setdefault((out[0].sensor, out[0].seq), []).append(
                        out[0].instance
                    )

            def on_fused(sample: zenoh.Sample) -> None:
                out = decode_vehicle_track_frame(sample.payload.to_bytes())
                assert not isinstance(out, Rejection), out
                with lock:
                    fused.append((out[0].stamp_ns, out[0].sensor, out[0].sensor_seq))

            subs = [
                session.declare_subscriber("fleet/*/*/tracks", on_tracks),
                session.declare_subscriber("fleet/*/@vehicle/tracks", on_fused),
            ]
            # Poses, not extrinsics: the old member reads DetectionFrame version 1 only
            # (vehicles upgrade after the services).
            pubs = {
                s: DetectionPublisher(session, "veh01", s, classes=CLASSES)
                for s in ("lidar", "camera")
            }
            assert all(p.wait_for_service(10) for p in pubs.values())
            wait_for(
                lambda: "simpletrack_group_members 2.0" in new.http("/metrics")[1],
                10,
                "the new member seeing the old",
            )
            t0, stamp0 = time.monotonic(), time.time_ns()
            sent: list[tuple[str, int, float]] = []
            stopped = None
            for sensor, seq, t in schedule(SECONDS):
                time.sleep(max(0.0, t0 + t - time.monotonic()))
                if stopped is None and t >= UPGRADE_AT:
                    stopped = threading.Thread(target=old.stop, args=(signal.SIGTERM,))
                    stopped.start()
                frame = world.frame(sensor, seq, t)
                pose = mount(0.0) if sensor == "lidar" else mount(1.5)
                pubs[sensor].publish(
                    frame.boxes, stamp_ns=stamp0 + round(t * 1e9), pose=pose, seq=seq
                )
                sent.append((sensor, seq, t))
            assert stopped is not None
            stopped.join(30)
            time.sleep(1.0)
            for s in subs:
                s.undeclare()
            for p in pubs.values():
                p.close()
            session.close()  # type: ignore[no-untyped-call]
        finally:
            with contextlib.suppress(Exception):
                old.stop(signal.SIGKILL)
            new.stop()
    before = [(s, q) for s, q, t in sent if t < UPGRADE_AT - 0.3]
    twice = {k: v for k, v in sensor_answers.items() if len(v) > 1}
    assert not twice, f"answered twice: {sorted(twice.items())[:5]}"
    unanswered = [k for k in before if k not in sensor_answers]
    assert not unanswered, f"owned by nobody: {unanswered[:10]}"
    owners = {i for k in before for i in sensor_answers[k]}
    assert owners <= {"m-old", "m-new"} and "m-old" in owners  # the old member did its share
    assert all(stamp >= stamp0 + (UPGRADE_AT - 0.5) * 1e9 for stamp, _, _ in fused), (
        "fused while the old member was in the group"
    )
    late = [(s, q) for s, q, t in sent if t > UPGRADE_AT + 1.5]
    fused_keys = {(s, q) for _, s, q in fused}
    assert late and all(k in fused_keys for k in late), "not fused after the upgrade"
    assert not any(k in sensor_answers for k in late), "still answered per sensor"
