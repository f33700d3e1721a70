"""Two members behind two routers whose link is cut for 8 s and healed; vehicles and the
planner are peers that reach both routers. While cut, each side takes the other's sensors
over (its standby copy, a higher custody epoch), so the wire carries two answers per frame;
through ``TrackSubscriber`` every frame comes once, with the tracks of an uninterrupted run.
Once healed, the old holders hear the higher epochs, fence themselves and ask for their
sensors back (docs/SCALE.md, "Fencing")."""

from __future__ import annotations

import threading
import time
from collections import Counter
from pathlib import Path

from simpletrack.client import TrackMessage, TrackSubscriber
from simpletrack.session import open_session
from simpletrack.spawn import free_port
from simpletrack.wire import TrackArrays
from tests.faults.link_proxy import LinkProxy
from tests.faults.router_process import Router, start_client_service
from tests.scale.fleet import Fleet, Planner, expected_tracks, needs_kitti, same_tracks
from tests.scale.test_a_stopped_member_publishes_nothing_stale import MEMBER, ROUTER, long_fleet
from tests.service_helpers import ServiceProcess, metric, wait_for

SENSORS = 10
FRAMES = 230


@needs_kitti
def test_a_partition_gives_a_planner_one_equal_answer_per_frame(tmp_path: Path) -> None:
    frames = dict(list(long_fleet().items())[:SENSORS])
    p1, pp, p2 = free_port(), free_port(), free_port()
    r1 = Router(f"tcp/127.0.0.1:{p1}", config=ROUTER).start()
    link = LinkProxy(pp, p1).start()
    r2 = Router(
        f"tcp/127.0.0.1:{p2}", config={**ROUTER, "connect/endpoints": [f"tcp/127.0.0.1:{pp}"]}
    ).start()
    (tmp_path / "member.json5").write_text(MEMBER)
    args = ("--zenoh-config", str(tmp_path / "member.json5"))
    env = {"SIMPLETRACK_QUEUE_SIZE": "1000"}
    members: dict[str, ServiceProcess] = {}
    fleet = None
    try:
        for name, router in (("m-a", r1), ("m-b", r2)):
            svc = start_client_service(tmp_path, router.endpoint, *args, env=env, instance=name)
            members[name] = svc
        for name, svc in members.items():
            wait_for(lambda svc=svc: svc.http("/readyz")[0] == 200, 60, f"{name} ready")
            wait_for(
                lambda svc=svc: metric(svc.metrics(), "simpletrack_group_members") == 2,
                20,
                f"{name} seeing the other",
            )
        both = [r1.endpoint, r2.endpoint]
        with open_session(mode="peer", connect=both) as session:
            planner = Planner()
            sub = session.declare_subscriber("fleet/*/*/tracks", planner.on_tracks)
            delivered: dict[tuple[str, int], list[TrackArrays]] = {}
            lock = threading.Lock()

            def deliver(m: TrackMessage) -> None:
                with lock:
                    delivered.setdefault((f"{m.vehicle}/{m.sensor}", m.seq), []).append(m.tracks)

            track_sub = TrackSubscriber(session, callback=deliver)
            fleet = Fleet(session, frames, cache_frames=200)
            assert fleet.wait_for_service(10)
            fleet.start()
            wait_for(lambda: fleet is not None and fleet.k >= 40, 20, "4 s of frames")
            link.cut()
            cut_ns = time.time_ns()
            wait_for(lambda: fleet is not None and fleet.k >= 120, 20, "8 s cut")
            link.heal()
            healed_ns = time.time_ns()
            wait_for(lambda: fleet is not None and fleet.done.is_set(), 60, "the whole run")
            time.sleep(3.0)
            sub.undeclare()
            track_sub.close()
        once = [k for k, v in delivered.items() if len(v) != 1]
        missing = [(n, q) for n in frames for q in range(FRAMES) if (n, q) not in delivered]
        assert not missing, (len(missing), missing[:10])
        assert not once, (len(once), once[:10])
        unequal = [
            (n, q)
            for n, payloads in frames.items()
            for q, e in enumerate(expected_tracks(n, payloads))
            if not same_tracks(delivered[n, q][0], e)
        ]
        assert not unequal, (len(unequal), unequal[:10])
        # The wire: both sides answered while cut, from different instances.
        with planner.lock:
            during = Counter(
                f.instance
                for v in planner.frames.values()
                for f, _ in v
                if cut_ns < f.published_ns < healed_ns
            )
        assert set(during) == {"m-a", "m-b"}, during
        superseded = sum(
            metric(m.metrics(), "simpletrack_fences_total", why="superseded")
            for m in members.values()
        )
        assert superseded > 0, "no holder heard the higher epoch after the heal"
    finally:
        if fleet is not None:
            fleet.close()
        for m in members.values():
            m.stop()
        link.cut()
        r1.stop()
        r2.stop()
