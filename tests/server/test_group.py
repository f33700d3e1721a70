"""Ownership by rendezvous hashing and the membership view: a change moves only the sensors
it must, every view agrees, and a client's own router outage is not taken for the group's."""

from __future__ import annotations

import threading
import time

from simpletrack.server.group import ROUTER_SETTLE_S, TICK_S, Membership, Role, ranking
from simpletrack.wire.keys import Keys

SENSORS = [f"car-{i}/lidar" for i in range(2000)]


def owners(members: set[str]) -> dict[str, str]:
    return {s: ranking(members, s)[0] for s in SENSORS}


def test_sensors_spread_evenly_over_the_members() -> None:
    counts: dict[str, int] = {}
    for owner in owners({"a", "b", "c", "d"}).values():
        counts[owner] = counts.get(owner, 0) + 1
    assert set(counts) == {"a", "b", "c", "d"}
    assert all(400 < n < 600 for n in counts.values()), counts


def test_a_member_leaving_moves_only_its_own_sensors_to_their_standby() -> None:
    before = owners({"a", "b", "c"})
    standby = {s: ranking({"a", "b", "c"}, s)[1] for s in SENSORS}
    after = owners({"a", "c"})
    for s in SENSORS:
        if before[s] != "b":
            assert after[s] == before[s]
        else:
            assert after[s] == standby[s]


def test_a_member_joining_takes_only_sensors_from_others_and_about_its_share() -> None:
    before = owners({"a", "b", "c"})
    after = owners({"a", "b", "c", "d"})
    moved = [s for s in SENSORS if before[s] != after[s]]
    assert all(after[s] == "d" for s in moved)
    assert 0.15 < len(moved) / len(SENSORS) < 0.35


def test_every_member_computes_the_same_owner_whatever_the_order() -> None:
    assert ranking(["c", "a", "b"], "v/s") == ranking(["b", "c", "a"], "v/s")


def test_roles_follow_the_view() -> None:
    m = Membership("a", Keys())
    sensor = next(s for s in SENSORS if ranking({"a", "b"}, s)[0] == "b")
    assert m.role(sensor) is Role.OWNER  # alone: everything
    m.token("b", True)
    assert m.role(sensor) is Role.STANDBY
    assert m.owner(sensor) == "b" and m.standby(sensor) == "a"
    m.token("b", False)  # peer mode: gone at once
    assert m.role(sensor) is Role.OWNER


def test_a_group_of_one_owns_everything_when_disabled() -> None:
    m = Membership("a", Keys(), enabled=False)
    m.token("b", True)
    assert all(m.role(s) is Role.OWNER for s in SENSORS[:50])


def test_a_client_without_its_router_keeps_the_members_it_cannot_see() -> None:
    routers = [1]
    m = Membership("a", Keys(), routers=lambda: routers[0])
    m._stop.clear()

    threading.Thread(target=m._tick, daemon=True).start()
    try:
        m.token("b", True)
        m.token("c", True)
        routers[0] = 0  # the router died: every token goes with it
        m.router_changed(False)
        m.token("b", False)
        m.token("c", False)
        time.sleep(5 * TICK_S)
        assert m.members == {"a", "b", "c"}
        routers[0] = 1
        m.router_changed(True)
        m.token("b", True)  # b comes back through the new router; c never does
        time.sleep(ROUTER_SETTLE_S + 5 * TICK_S)
        assert m.members == {"a", "b"}
    finally:
        m.close()


def test_a_client_with_its_router_sees_a_member_go_within_a_tick() -> None:
    m = Membership("a", Keys(), routers=lambda: 1)

    threading.Thread(target=m._tick, daemon=True).start()
    try:
        m.token("b", True)
        m.token("b", False)
        time.sleep(5 * TICK_S)
        assert m.members == {"a"}
    finally:
        m.close()


def test_vehicles_fuse_only_while_every_member_in_view_can() -> None:
    m = Membership("a", Keys())
    assert not m.fusion_gate()  # this member was given no fusion settings
    m.fuses = True
    assert m.fusion_gate()  # alone
    m.token("b", True)  # a member of before fusion: no fusion token
    assert not m.fusion_gate()
    m.can_fuse("b")
    assert m.fusion_gate()
    m.token("c", True)
    assert not m.fusion_gate()
    m.token("c", False)
    assert m.fusion_gate()
    m.token("b", False)  # gone: able again only with a new token
    m.token("b", True)
    assert not m.fusion_gate()
    m.can_fuse("b")
    assert m.fusion_gate()


def test_a_fused_sensors_stream_follows_the_gate_and_its_worker_never_moves() -> None:
    from simpletrack.server.streams import Streams

    gate = [True]
    keys = Keys()
    streams = Streams(keys, frozenset({"lidar", "camera"}), gate=lambda: gate[0])
    assert streams.stream("veh01", "lidar") == "veh01/@vehicle"
    assert streams.stream("veh01", "radar") == "veh01/radar"  # not a fused sensor
    route = streams.route(keys.detections("veh01", "camera"))
    gate[0] = False  # a member of before fusion joined: every sensor its own stream
    assert streams.stream("veh01", "lidar") == "veh01/lidar"
    assert streams.route(keys.detections("veh01", "camera")) == route  # same worker
    assert route == streams.route(keys.detections("veh01", "lidar"))
    only = Streams(keys, frozenset({"lidar"}), frozenset({"veh02"}))
    assert only.stream("veh01", "lidar") == "veh01/lidar"
    assert only.stream("veh02", "lidar") == "veh02/@vehicle"
