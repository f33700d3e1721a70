"""The standby keeps only ``standby_frames`` frames since the owner's last checkpoint. When
the owner dies after more than that, the new owner asks the vehicles' caches for the frames
in between: with the cache covering them, the tracks equal an uninterrupted tracker's; with
a cache too small, the frames neither kept are counted and announced as missed, the tracks
alive in the checkpoint keep their ids, and every track born after the takeover gets an id
above all the dead owner published."""

from __future__ import annotations

import signal
import threading
import time
from pathlib import Path

import pytest
import zenoh

from simpletrack.wire import FrameError, Rejection, decode_message
from tests.scale.fleet import (
    Fleet,
    Group,
    Planner,
    fleet_frames,
    mismatches,
    needs_kitti,
    planner_session,
)
from tests.service_helpers import metric, wait_for

SENSORS = 4


@needs_kitti
@pytest.mark.parametrize("vehicle_cache", [100, 5])
def test_a_gap_beyond_the_standby_is_replayed_from_the_vehicles_or_announced(
    tmp_path: Path, vehicle_cache: int
) -> None:
    frames = fleet_frames(SENSORS, 150)
    env = {"SIMPLETRACK_STANDBY_FRAMES": "5", "SIMPLETRACK_CHECKPOINT_INTERVAL_S": "30"}
    group = Group(tmp_path)
    fleet = None
    errors: list[FrameError] = []
    lock = threading.Lock()

    def on_error(sample: zenoh.Sample) -> None:
        err = decode_message(sample.payload.to_bytes(), FrameError)
        assert not isinstance(err, Rejection)
        with lock:
            errors.append(err)

    try:
        for name in ("m-a", "m-b"):
            group.add(name, env=env)
        with planner_session(group) as session:
            planner = Planner()
            subs = [
                session.declare_subscriber("fleet/*/*/tracks", planner.on_tracks),
                session.declare_subscriber("fleet/*/*/errors", on_error),
            ]
            fleet = Fleet(session, frames, cache_frames=vehicle_cache)
            assert fleet.wait_for_service(10)
            fleet.start()
            # The first checkpoint goes at 30 s: the standby has the first 5 s of frames
            # only as its last 5 frames.
            wait_for(lambda: fleet.k >= 50, 20, "5 s of frames")
            before = planner.instances()
            victim = before.most_common(1)[0][0]
            group.remove(victim).stop(signal.SIGKILL)
            killed_ns = time.time_ns()
            wait_for(lambda: fleet.k >= 80, 20, "3 s after the kill")
            sent = fleet.k + 1
            fleet.close()
            time.sleep(0.5)
            for s in subs:
                s.undeclare()
        survivor = next(iter(group.members.values()))
        assert metric(survivor.metrics(), "simpletrack_failovers_total") > 0
        with lock:
            missed = [e for e in errors if e.reason.value == "missed"]
        if vehicle_cache == 100:  # the vehicles still had every frame of the gap
            assert not missed, [e.detail for e in missed]
            counts, unequal, _ = mismatches(planner, frames, sent)
            assert not counts, counts[:10]
            assert not unequal, unequal[:10]
            return
        assert missed, "no missed notice"
        with planner.lock:
            got = {k: list(v) for k, v in planner.frames.items()}
        moved = {e.vehicle + "/" + e.sensor for e in missed}
        for name in moved:
            old = [(f, t) for f, t in got[name] if f.instance == victim]
            new = [
                (f, t) for f, t in got[name] if f.instance != victim and f.published_ns > killed_ns
            ]
            assert old and new, name
            used = {int(i) for _, t in old for i in t.id}
            after = {int(i) for _, t in new for i in t.id}
            # Ids of the checkpoint's tracks come back; every other id is new, above all.
            born = after - used
            assert born and min(born) > max(used), (name, sorted(used), sorted(after))
    finally:
        try:
            if fleet is not None:
                fleet.close()
        finally:
            group.stop_all()
