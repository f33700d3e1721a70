"""Three members share 30 sensors replaying KITTI at 10 Hz through a router; vehicles keep
their last 200 frames. The members announce a 3 s Zenoh lease and the router closes a link
whose queue stays full for 1 s (docs/SCALE.md, "Hung member": how to shorten the wait). The
busiest member is stopped with SIGSTOP for 12 s (past the lease: the group takes its sensors
over) and then continued. A raw subscriber sees every
frame answered, every message equal to an uninterrupted tracker's tracks (at most two
identical repeats per moved sensor: a failover publishes again the last frame its standby
was told of, and the one after it if that went out before its word: server/told.py), and
none stale: no message with a lower custody epoch than one already published on its key
(the resumed member fences itself before it tracks anything: docs/SCALE.md, "Fencing"), but
for at most one message a sensor that the member had handed to Zenoh before the stop and
that arrived after the takeover (its frame was sent before the stop)."""

from __future__ import annotations

import os
import signal
import time
from collections import Counter
from pathlib import Path

from simpletrack.wire import BoxArrays, TrackArrays, TrackFrame
from tests.faults.router_process import new_router
from tests.scale.fleet import (
    Fleet,
    Group,
    Planner,
    expected_tracks,
    fleet_frames,
    needs_kitti,
    planner_session,
    same_tracks,
)
from tests.service_helpers import metric, wait_for

SENSORS = 30
FRAMES = 230  # 23 s: 4 s before the stop, 12 s stopped, 7 s after
STOPPED_S = 12.0
# The deploy's routers close a link whose queue has been full this long (deploy/zenoh): a
# stopped member's socket buffers fill in seconds, and with Zenoh's default (5 s) every
# member behind the router waits on it meanwhile.
ROUTER = {"transport/link/tx/queue/congestion_control/block/wait_before_close": 1_000_000}
MEMBER = "{ transport: { link: { tx: { lease: 3000, keep_alive: 4 } } } }"  # ms


def long_fleet() -> dict[str, list[BoxArrays]]:
    """30 sensors replaying the KITTI sequences that have ``FRAMES`` frames."""
    pool = [v for v in fleet_frames(10, FRAMES).values() if len(v) == FRAMES]
    return {f"car-{i}/lidar": pool[i % len(pool)] for i in range(SENSORS)}


@needs_kitti
def test_a_member_stopped_past_the_lease_publishes_nothing_stale(tmp_path: Path) -> None:
    frames = long_fleet()
    router = new_router(ROUTER).start()
    (tmp_path / "member.json5").write_text(MEMBER)
    group = Group(tmp_path, ("--zenoh-config", str(tmp_path / "member.json5")), router.endpoint)
    fleet = None
    victim = None
    try:
        for name in ("m-a", "m-b", "m-c"):
            group.add(name)
        with planner_session(group) as session:
            planner = Planner()
            sub = session.declare_subscriber("fleet/*/*/tracks", planner.on_tracks)
            fleet = Fleet(session, frames, cache_frames=200)
            assert fleet.wait_for_service(10)
            fleet.start()
            wait_for(lambda: fleet is not None and fleet.k >= 40, 20, "4 s of frames")
            busiest = planner.instances().most_common(1)[0][0]
            victim = group.members[busiest]
            os.kill(victim.proc.pid, signal.SIGSTOP)
            stopped_k = fleet.k  # frames sent before the stop: the member may have tracked them
            stopped_ns = time.time_ns()
            time.sleep(STOPPED_S)
            os.kill(victim.proc.pid, signal.SIGCONT)
            wait_for(lambda: fleet is not None and fleet.done.is_set(), 60, "the whole run")
            time.sleep(3.0)  # the last frames' answers
            sub.undeclare()
        with planner.lock:
            got: dict[str, list[tuple[TrackFrame, TrackArrays]]] = {
                k: list(v) for k, v in planner.frames.items()
            }
        stale, unanswered, unequal, repeats = [], [], [], Counter[str]()
        in_flight: list[str] = []
        repeated: list[str] = []  # who published each repeated answer, when (vs the stop)
        for name, payloads in frames.items():
            expected = expected_tracks(name, payloads)
            top = -1
            by_seq: dict[int, list[TrackArrays]] = {}
            who: dict[int, list[str]] = {}
            for f, t in got.get(name, []):  # arrival order
                assert f.epoch is not None, "every message carries its epoch"
                if f.epoch < top:
                    late = f"{name} seq {f.seq} from {f.instance} epoch {f.epoch} < {top}"
                    # A message the member handed to Zenoh before the stop can still be in
                    # its transmit queue and arrive after the takeover: sent before, not
                    # published from stale state after. Anything later is stale.
                    (in_flight if f.seq <= stopped_k + 1 else stale).append(late)
                top = max(top, f.epoch)
                by_seq.setdefault(f.seq, []).append(t)
                who.setdefault(f.seq, []).append(
                    f"{f.instance} e{f.epoch} +{(f.published_ns - stopped_ns) / 1e6:.0f}ms"
                )
            for seq in range(FRAMES):
                answers = by_seq.get(seq, [])
                if not answers:
                    unanswered.append(f"{name} seq {seq}")
                repeats[name] += max(0, len(answers) - 1)
                if len(answers) > 1:
                    repeated.append(f"{name} seq {seq}: {who[seq]}")
                unequal += [
                    f"{name} seq {seq}" for a in answers if not same_tracks(a, expected[seq])
                ]
        assert not stale, stale[:10]
        assert len(in_flight) <= len({x.split()[0] for x in in_flight}), in_flight  # 1 a sensor
        assert not unanswered, (len(unanswered), unanswered[:10])
        assert not unequal, (len(unequal), unequal[:10])
        assert max(repeats.values()) <= 2, (repeats.most_common(5), repeated[:10])
        # The group took the stopped member's sensors over, and it took them back.
        theirs = {n for n, v in got.items() if any(f.instance == busiest for f, _ in v)}
        moved = {
            n
            for n in theirs
            if any(f.instance != busiest and f.published_ns > stopped_ns for f, _ in got[n])
        }
        assert moved == theirs, sorted(theirs - moved)
        logs = victim.logs()
        assert [x for x in logs if x.get("event") == "sensor_fenced"], "nothing fenced"
        back = [x["source"] for x in logs if x.get("event") == "sensor_taken_over"]
        assert back.count("handoff") == len(theirs), back
        fences = metric(victim.metrics(), "simpletrack_fences_total", why="stopped")
        assert fences == len(theirs), fences
    finally:
        if victim is not None:
            os.kill(victim.proc.pid, signal.SIGCONT)
        try:
            if fleet is not None:
                fleet.close()
        finally:
            group.stop_all()
            router.stop()
