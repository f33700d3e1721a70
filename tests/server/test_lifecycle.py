"""The service over its life: restart from snapshots, crash, overload, idle eviction."""

from __future__ import annotations

import signal
from pathlib import Path

import msgpack
import numpy as np
import pytest

from simpletrack.wire import ErrorReason, Rejection, SensorSnapshot, ServiceStatus, decode_message
from tests.service_helpers import (
    Client,
    client,
    metric,
    moving_cars,
    stamp,
    start_service,
    wait_for,
)

pytestmark = pytest.mark.zenoh


def crossing(k: int) -> object:
    """Objects that appear, cross and vanish, so ids are born and die mid-sequence."""
    boxes = moving_cars(k, n=4)
    keep = np.array([k < 9 or k >= 15, True, k >= 5, 3 <= k < 20])
    centre = boxes.center.copy()
    centre[:, 1] += 0.3 * np.sin(k / 3.0)
    return type(boxes)(
        classes=boxes.classes,
        class_index=boxes.class_index[keep],
        center=centre[keep],
        size=boxes.size[keep],
        yaw=boxes.yaw[keep],
        score=np.linspace(0.95, 0.75, 4, dtype=np.float32)[keep],
    )


def send_range(cli: Client, sensor: str, first: int, last: int) -> None:
    for k in range(first, last):
        cli.send("veh", sensor, seq=k, stamp_ns=stamp(k), boxes=crossing(k))  # type: ignore[arg-type]


def tracker_state_format(path: Path) -> int:
    """The byte form of the tracker state in a snapshot file (core/tracker.py)."""
    snap = decode_message(path.read_bytes(), SensorSnapshot)
    assert not isinstance(snap, Rejection) and snap.tracker is not None
    return int(msgpack.unpackb(snap.tracker, raw=False)["format"])


def test_sigterm_mid_sequence_then_restart_equals_an_uninterrupted_run(tmp_path: Path) -> None:
    """Also across the two state formats: the first instance is pinned to the form of the
    versions before compact states (a rolling upgrade), the second reads it and writes its own."""
    state = tmp_path / "state"
    n, cut = 24, 11
    a = start_service(
        tmp_path, "--state-dir", str(state), instance="svc-a", env={"SIMPLETRACK_STATE_FORMAT": "1"}
    )
    with client(a.endpoint) as cli:
        send_range(cli, "cut", 0, cut)
        wait_for(lambda: cli.received.n_tracks("veh/cut") == cut, 20, "first half")
        first = list(cli.received.tracks["veh/cut"])
    assert a.stop(signal.SIGTERM) == 0
    assert tracker_state_format(state / "veh" / "cut.snap") == 1

    b = start_service(tmp_path, "--state-dir", str(state), instance="svc-b")
    try:
        with client(b.endpoint) as cli:
            [raw] = cli.get("fleet/@simpletrack/svc-b/status")
            status = decode_message(raw, ServiceStatus)
            assert not isinstance(status, Rejection)
            assert [(s.vehicle, s.sensor, s.last_seq) for s in status.sensors] == [
                ("veh", "cut", cut - 1)
            ]
            send_range(cli, "cut", cut, n)
            send_range(cli, "whole", 0, n)  # the uninterrupted reference run
            wait_for(lambda: cli.received.n_tracks("veh/cut") == n - cut, 20, "second half")
            wait_for(lambda: cli.received.n_tracks("veh/whole") == n, 20, "reference run")
            resumed = first + cli.received.tracks["veh/cut"]
            whole = cli.received.tracks["veh/whole"]
        assert metric(b.metrics(), "simpletrack_sensors_restored_total") == 1
    finally:
        assert b.stop() == 0
    assert tracker_state_format(state / "veh" / "cut.snap") == 2
    assert [f.seq for f, _ in resumed] == list(range(n))
    assert any(len(t) for _, t in resumed[cut:])
    ids = {int(i) for _, t in resumed for i in t.id}
    assert len(ids) == 5  # one track died before the cut and its object came back after it
    for k, ((_, r), (_, w)) in enumerate(zip(resumed, whole, strict=True)):
        for name in ("id", "class_index", "center", "size", "yaw", "score", "velocity", "state"):
            np.testing.assert_array_equal(getattr(r, name), getattr(w, name), err_msg=f"{k} {name}")
        np.testing.assert_array_equal(r.hits, w.hits)
        np.testing.assert_array_equal(r.age, w.age)


def test_sigkill_loses_at_most_the_frames_since_the_last_periodic_snapshot(
    tmp_path: Path,
) -> None:
    state = tmp_path / "state"
    env = {"SIMPLETRACK_SNAPSHOT_INTERVAL_S": "0.3"}
    a = start_service(tmp_path, "--state-dir", str(state), env=env, instance="svc-k")
    with client(a.endpoint) as cli:
        send_range(cli, "crash", 0, 6)
        wait_for(lambda: cli.received.n_tracks("veh/crash") == 6, 20, "6 frames")
        # The periodic snapshot of frame 5 lands within ~interval + housekeeping tick.
        wait_for(lambda: _snapshot_seq(state / "veh" / "crash.snap") == 5, 5, "periodic snapshot")
    a.stop(signal.SIGKILL)

    b = start_service(tmp_path, "--state-dir", str(state), env=env, instance="svc-k")
    try:
        with client(b.endpoint) as cli:
            send_range(cli, "crash", 6, 8)
            wait_for(lambda: cli.received.n_tracks("veh/crash") == 2, 20, "resumed frames")
            assert cli.received.n_errors("veh/crash") == 0
            assert all(len(t) for _, t in cli.received.tracks["veh/crash"])
            # Continued, not reborn: the oldest track has lived through frames 0-6.
            _, first_after = cli.received.tracks["veh/crash"][0]
            assert int(first_after.age.max()) == 6 and int(first_after.hits.max()) == 7
    finally:
        b.stop()


def _snapshot_seq(path: Path) -> int | None:
    if not path.is_file():
        return None
    snap = decode_message(path.read_bytes(), SensorSnapshot)
    return None if isinstance(snap, Rejection) else snap.last_seq


def test_overload_drops_oldest_with_a_reason_and_idle_sensors_are_evicted(tmp_path: Path) -> None:
    env = {
        "SIMPLETRACK_QUEUE_SIZE": "2",
        "SIMPLETRACK_WORKERS": "1",
        "SIMPLETRACK_SENSOR_IDLE_S": "1.0",
    }
    svc = start_service(tmp_path, env=env, instance="svc-o")
    try:
        with client(svc.endpoint) as cli:
            n = 150
            heavy = [moving_cars(k, n=300) for k in range(n)]
            for k in range(n):  # far faster than 300-box frames can be tracked
                cli.send("veh", "flood", seq=k, stamp_ns=stamp(k), boxes=heavy[k])

            def named() -> list[int | None]:  # a drop notice names every frame it stands for
                with cli.received.lock:
                    errors = list(cli.received.errors.get("veh/flood", []))
                return [s for e in errors for s in (e.seqs if e.seqs is not None else [e.seq])]

            done = lambda: cli.received.n_tracks("veh/flood") + len(named())  # noqa: E731
            wait_for(lambda: done() == n, 60, "every frame accounted for")
            notices = cli.received.errors.get("veh/flood", [])
            assert notices, "the flood should overflow a queue of 2"
            assert {e.reason for e in notices} == {ErrorReason.DROPPED_QUEUE_FULL}
            tracked = [f.seq for f, _ in cli.received.tracks["veh/flood"]]
            assert tracked == sorted(tracked) and tracked[-1] == n - 1  # newest kept, in order
            dropped = named()
            assert sorted(tracked + dropped) == list(range(n))  # type: ignore[operator]
            m = svc.metrics()
            name = "simpletrack_frames_dropped_total"
            assert metric(m, name, reason="dropped_queue_full") == len(dropped)
            assert metric(m, "simpletrack_frames_received_total") == n
            assert metric(m, "simpletrack_frames_tracked_total") == len(tracked)

            # Idle eviction: after sensor_idle_s the sensor's state goes; its ids stay used.
            last_ids = set(cli.received.tracks["veh/flood"][-1][1].id.tolist())
            wait_for(
                lambda: metric(svc.metrics(), "simpletrack_sensors_evicted_total") == 1,
                10,
                "eviction",
            )
            assert metric(svc.metrics(), "simpletrack_active_sensors") == 0
            cli.send("veh", "flood", seq=n, stamp_ns=stamp(n), boxes=moving_cars(n))
            wait_for(lambda: done() == n + 1, 20, "the frame after eviction")
            new_ids = set(cli.received.tracks["veh/flood"][-1][1].id.tolist())
            assert min(new_ids) > max(last_ids)
    finally:
        assert svc.stop() == 0
