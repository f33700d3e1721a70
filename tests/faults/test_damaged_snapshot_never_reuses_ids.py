"""Item 10: ids are never reused, whatever happens to a snapshot file. A service with a state
directory tracks objects, stops (SIGTERM or SIGKILL), its snapshot is truncated, garbled,
deleted or replaced by an older copy, and a new service tracks new objects: every id born
after the restart is above every id published before it."""

from __future__ import annotations

import signal
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from simpletrack.core.tracker import Tracker
from simpletrack.server.snapshots import decode_ids, encode_ids
from simpletrack.wire import BoxArrays, Rejection, SensorSnapshot, decode_message
from tests.service_helpers import Client, client, moving_cars, stamp, start_service, wait_for

pytestmark = pytest.mark.zenoh
ENV = {"SIMPLETRACK_SNAPSHOT_INTERVAL_S": "0.3"}


def cars(k: int, y: float) -> BoxArrays:
    """Three cars of frame k, ``y`` metres across from the first group (no overlap)."""
    boxes = moving_cars(k)
    center = boxes.center.copy()
    center[:, 1] += y
    return replace(boxes, center=center)


def both(k: int) -> BoxArrays:
    a, b = cars(k, 0.0), cars(k, 100.0)
    return replace(
        a,
        class_index=np.concatenate([a.class_index, b.class_index]),
        center=np.concatenate([a.center, b.center]),
        size=np.concatenate([a.size, b.size]),
        yaw=np.concatenate([a.yaw, b.yaw]),
        score=np.concatenate([a.score, b.score]),
    )


def send(cli: Client, frames: range, make: object) -> list[int]:
    """Send frames, wait for their tracks; the ids they carried."""
    before = cli.received.n_tracks("veh/lidar")
    for k in frames:
        cli.send("veh", "lidar", seq=k, stamp_ns=stamp(k), boxes=make(k))  # type: ignore[operator]
    wait_for(lambda: cli.received.n_tracks("veh/lidar") == before + len(frames), 20, "tracks")
    with cli.received.lock:
        errors = list(cli.received.errors.get("veh/lidar", []))
    # A restart from an older copy finds the frames after it in no cache (plain puts): the
    # gap is announced as missed, nothing else is refused.
    assert all(e.reason.value == "missed" for e in errors), errors
    return [int(i) for _, t in cli.received.tracks["veh/lidar"][before:] for i in t.id]


def snapshot(path: Path) -> SensorSnapshot | None:
    if not path.is_file():
        return None
    snap = decode_message(path.read_bytes(), SensorSnapshot)
    return None if isinstance(snap, Rejection) else snap


def snapshot_ids(snap: SensorSnapshot) -> set[int]:
    assert snap.tracker is not None
    tracker = Tracker.from_bytes(snap.tracker)
    return {int(i) + snap.id_base for i in tracker.tracks.ids}


DAMAGE = {
    "truncated": lambda p, old: p.write_bytes(p.read_bytes()[: p.stat().st_size // 2]),
    "emptied": lambda p, old: p.write_bytes(b""),
    "garbled": lambda p, old: p.write_bytes(
        bytes(np.random.default_rng(1).bytes(p.stat().st_size))
    ),
    "deleted": lambda p, old: p.unlink(),
    "older copy": lambda p, old: p.write_bytes(old),
}


@pytest.mark.parametrize(
    ("damage", "sig"),
    [
        ("truncated", signal.SIGKILL),
        ("emptied", signal.SIGTERM),
        ("garbled", signal.SIGTERM),
        ("deleted", signal.SIGKILL),
        ("deleted", signal.SIGTERM),
        ("older copy", signal.SIGKILL),
    ],
    ids=lambda v: v.name if isinstance(v, signal.Signals) else v,
)
def test_a_damaged_snapshot_never_brings_ids_back(
    tmp_path: Path, damage: str, sig: signal.Signals
) -> None:
    state = tmp_path / "state"
    snap_path = state / "veh" / "lidar.snap"
    a = start_service(tmp_path, "--state-dir", str(state), env=ENV, instance="svc-a")
    with client(a.endpoint) as cli:
        before = send(cli, range(0, 6), lambda k: cars(k, 0.0))
        wait_for(lambda: (s := snapshot(snap_path)) is not None and s.last_seq == 5, 10, "snap")
        old = snap_path.read_bytes()  # what a backup taken now would hold
        before += send(cli, range(6, 12), both)  # three more objects, born after that copy
        wait_for(lambda: (s := snapshot(snap_path)) is not None and s.last_seq == 11, 10, "snap")
    if sig is signal.SIGKILL:
        a.stop(sig)
    else:
        assert a.stop(sig) == 0
    assert len(set(before)) == 6

    DAMAGE[damage](snap_path, old)
    restored = snapshot(snap_path)
    continued = snapshot_ids(restored) if restored is not None else set()

    b = start_service(tmp_path, "--state-dir", str(state), env=ENV, instance="svc-b")
    try:
        with client(b.endpoint) as cli:
            after = send(cli, range(12, 18), lambda k: cars(k, 300.0))  # new objects only
            missed = cli.received.n_errors("veh/lidar")
    finally:
        assert b.stop() == 0
    assert missed == (1 if damage == "older copy" else 0)  # seqs 6-11: announced, not silent
    born = set(after) - continued
    assert len(born) == 3
    assert min(born) > max(before), (sorted(before), sorted(after))
    assert not (set(after) - continued) & set(before)


def test_a_damaged_id_reservation_is_seen_not_read() -> None:
    good = encode_ids("veh", "lidar", 2048)
    assert decode_ids(good) == ("veh", "lidar", 2048)
    flipped = good.replace(b"2048", b"2049")  # the checksum no longer agrees
    for bad in (flipped, good[:-3], b"", b"\xff" * len(good), good + good):
        assert decode_ids(bad) is None, bad
