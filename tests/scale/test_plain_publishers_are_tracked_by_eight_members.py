"""Eight members under the default settings (``subscribe = "owned"``) and a fleet of plain
publishers (declared publishers, no advanced publisher's token, no cache): the group's scout
finds each sensor, its owner subscribes and takes the frames sent before that from the scout,
so every frame, the first ones included, is answered once, with the tracks one uninterrupted
tracker gives. And no member pays for the others' sensors: each hears only the frames of the
sensors it owns or stands by for (the scout's key parse aside), none is refused as not owned."""

from __future__ import annotations

import time
from pathlib import Path

import zenoh

from simpletrack.wire.codec import encode_detection_frame
from tests.scale.fleet import (
    PERIOD_S,
    Group,
    Planner,
    fleet_frames,
    mismatches,
    needs_kitti,
    planner_session,
    stamp_of,
)
from tests.service_helpers import wait_for

MEMBERS = 8
SENSORS = 16
FRAMES = 30  # 3 s


def _received(values: dict[str, float], name: str) -> float:
    return sum(v for k, v in values.items() if k.split("{")[0] == name)


@needs_kitti
def test_plain_puts_are_tracked_whole_and_each_member_hears_its_share(tmp_path: Path) -> None:
    frames = fleet_frames(SENSORS, FRAMES)
    group = Group(tmp_path)
    try:
        for i in range(MEMBERS):
            group.add(f"m{i}")
        with planner_session(group) as session:
            planner = Planner()
            sub = session.declare_subscriber("fleet/*/*/tracks", planner.on_tracks)
            pubs = {
                name: session.declare_publisher(
                    f"fleet/{name}/detections", congestion_control=zenoh.CongestionControl.BLOCK
                )
                for name in frames
            }
            for key, pub in pubs.items():  # the scout's subscriber, before the first put
                wait_for(lambda p=pub: p.matching_status.matching, 20, f"a subscriber of {key}")
            t0 = time.monotonic()
            for k in range(FRAMES):
                time.sleep(max(0.0, t0 + k * PERIOD_S - time.monotonic()))
                for name, pub in pubs.items():
                    vehicle, sensor = name.split("/")
                    pub.put(
                        encode_detection_frame(
                            vehicle=vehicle,
                            sensor=sensor,
                            seq=k,
                            stamp_ns=stamp_of(k),
                            frame_id=sensor,
                            boxes=frames[name][k],
                        )
                    )
            wait_for(lambda: planner.count() >= SENSORS * FRAMES, 30, "every frame's tracks")
            time.sleep(0.5)  # anything answered twice arrives too
            counts, unequal, repeats = mismatches(planner, frames, FRAMES)
            owners = planner.instances()
            metrics = {name: svc.metrics() for name, svc in group.members.items()}
            sub.undeclare()
            for pub in pubs.values():
                pub.undeclare()
    finally:
        group.stop_all()
    assert not counts and not unequal and repeats == 0, (counts[:5], unequal[:5])
    assert len(owners) >= MEMBERS // 2, owners  # the sensors spread over the group
    heard = {m: _received(v, "simpletrack_frames_received_total") for m, v in metrics.items()}
    not_owned = {m: _received(v, "simpletrack_frames_not_owned_total") for m, v in metrics.items()}
    # Owner and standby hear each frame; every other member none of it.
    assert sum(heard.values()) <= 2 * SENSORS * FRAMES, heard
    assert sum(not_owned.values()) == 0, not_owned
