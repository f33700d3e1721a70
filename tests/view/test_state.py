"""What /state.json and /events serve: the latest frame per sensor, as published."""

from __future__ import annotations

import json
import math
import time
import urllib.request
from typing import Any

import pytest

from simpletrack.view.server import MAX_PUSH_HZ
from simpletrack.wire import WireTrackState
from tests.service_helpers import wait_for
from tests.view.conftest import Rig
from tests.view.frames import Known, Sender, pose_at

pytestmark = pytest.mark.zenoh

TRACKS = [
    Known(11, 12.0, 3.0, 4.5, 1.9, 0.25, WireTrackState.CONFIRMED, vx=5.0, vy=1.0),
    Known(12, -6.0, 8.0, 4.0, 1.8, -1.0, WireTrackState.TENTATIVE),
    Known(13, 20.0, -7.5, 0.8, 0.7, 2.0, WireTrackState.COASTING, cls=1),
]


def get_json(url: str) -> Any:
    with urllib.request.urlopen(url, timeout=5) as r:
        return json.loads(r.read())


def state(rig: Rig) -> dict[str, Any]:
    out: dict[str, Any] = get_json(rig.view.url + "state.json")["sensors"]
    return out


def test_state_json_holds_the_latest_tracks_ego_and_detections_of_each_sensor(rig: Rig) -> None:
    lidar = rig.sender("veh01", "lidar", detections=True)
    front = rig.sender("veh02", "front")
    pose = pose_at(5.0, -2.0, math.pi / 2)
    lidar.tracks(TRACKS[:1])  # an older frame: the next one replaces it
    lidar.tracks(TRACKS, pose=pose)
    # The detections in the sensor frame: with the pose they land where the tracks are.
    c, s = math.cos(-math.pi / 2), math.sin(-math.pi / 2)
    local = [
        Known(t.id, c * (t.x - 5.0) - s * (t.y + 2.0), s * (t.x - 5.0) + c * (t.y + 2.0),
              t.l, t.w, t.yaw - math.pi / 2, t.state)
        for t in TRACKS
    ]  # fmt: skip
    lidar.detections(local, pose=pose)
    front.tracks(TRACKS[1:2], stamp_ns=time.time_ns() + 60 * 10**9)  # a clock a minute ahead
    wait_for(
        lambda: (
            (s := state(rig)).keys() == {"veh01/lidar", "veh02/front"}
            and s["veh01/lidar"]["seq"] == 2
            and s["veh01/lidar"]["detections"] is not None
        ),
        10,
        "both sensors in /state.json",
    )
    sensors = state(rig)
    got = sensors["veh01/lidar"]
    assert [(t["id"], t["x"], t["y"], t["state"]) for t in got["tracks"]] == [
        (11, 12.0, 3.0, "confirmed"),
        (12, -6.0, 8.0, "tentative"),
        (13, 20.0, -7.5, "coasting"),
    ]
    assert got["tracks"][0]["vx"] == 5.0 and got["tracks"][2]["class"] == "pedestrian"
    assert got["ego"] == {"x": 5.0, "y": -2.0, "yaw": round(math.pi / 2, 4)}
    assert got["fov"] == {"deg": 90.0, "range": 30.0}
    assert got["frame_id"] == "world"
    dets = got["detections"]["boxes"]
    for box, t in zip(dets, TRACKS, strict=True):
        assert box["x"] == pytest.approx(t.x, abs=1e-3)
        assert box["y"] == pytest.approx(t.y, abs=1e-3)
        assert math.remainder(box["yaw"] - t.yaw, 2 * math.pi) == pytest.approx(0, abs=1e-3)
    stats = got["stats"]
    assert stats["frames"] == 2 and stats["tracks"] == 3 and stats["tracks_per_frame"] == 2.0
    assert stats["by_state"] == {"tentative": 1, "confirmed": 1, "coasting": 1}
    assert stats["latency_s"] >= 0
    ahead = sensors["veh02/front"]
    assert ahead["ego"] is None and ahead["fov"] is None and ahead["detections"] is None
    assert ahead["stats"]["latency_s"] == pytest.approx(-60.0, abs=5.0)


def events(url: str, count: int, timeout: float = 10.0) -> list[dict[str, Any]]:
    """The first ``count`` pushes of an event stream."""
    out: list[dict[str, Any]] = []
    with urllib.request.urlopen(url, timeout=timeout) as r:
        assert r.headers["Content-Type"] == "text/event-stream"
        for line in r:
            if line.startswith(b"data: "):
                out.append(json.loads(line[6:]))
                if len(out) == count:
                    break
    return out


def test_events_push_the_chosen_sensor_latest_wins_at_a_bounded_rate(rig: Rig) -> None:
    lidar = rig.sender("veh01", "lidar")
    front = rig.sender("veh02", "front")
    front.tracks(TRACKS[1:])
    lidar.tracks(TRACKS[:1])
    wait_for(lambda: len(state(rig)) == 2, 10, "both sensors")
    first = events(rig.view.url + "events?sensor=veh02/front", 1)[0]
    assert first["names"] == ["veh01/lidar", "veh02/front"]
    assert first["frame"]["name"] == "veh02/front"
    assert [t["id"] for t in first["frame"]["tracks"]] == [12, 13]

    # A burst of 60 frames: the stream skips to the newest instead of queueing them all.
    seen: list[int] = []
    started = time.monotonic()
    with urllib.request.urlopen(rig.view.url + "events?sensor=veh01/lidar", timeout=10) as r:
        for _ in range(60):
            lidar.tracks(TRACKS)
        for line in r:
            if line.startswith(b"data: "):
                seen.append(json.loads(line[6:])["frame"]["seq"])
                if seen[-1] == 61:
                    break
    elapsed = time.monotonic() - started
    assert seen[-1] == 61, seen
    assert len(seen) < 30, f"{len(seen)} pushes for a burst of 60 frames"
    # Pushes are at least 1/MAX_PUSH_HZ apart, however fast frames come.
    assert len(seen) <= elapsed * MAX_PUSH_HZ + 1, (len(seen), elapsed)


@pytest.mark.parametrize("rig", [{"sensors": ["veh01/*"]}], indirect=True)
def test_a_sensor_filter_keeps_other_vehicles_out(rig: Rig) -> None:
    lidar = rig.sender("veh01", "lidar")
    veh02 = Sender(rig.publisher, "veh02", "front")  # nobody subscribes: no match to wait for
    veh02.tracks(TRACKS)
    lidar.tracks(TRACKS)
    wait_for(lambda: "veh01/lidar" in state(rig), 10, "veh01/lidar")
    veh02.tracks(TRACKS)
    lidar.tracks(TRACKS)
    wait_for(lambda: state(rig)["veh01/lidar"]["seq"] == 2, 10, "the second frame")
    assert list(state(rig)) == ["veh01/lidar"]
    assert get_json(rig.view.url + "state.json")["detections_enabled"] is False


@pytest.mark.parametrize(
    "rig", [{"sensors": ["veh02/@vehicle"], "detections": True}], indirect=True
)
def test_a_fused_vehicle_filter_takes_its_fused_stream_and_its_sensors_detections(
    rig: Rig,
) -> None:
    from tests.view.frames import VehicleSender, detection_frame, vehicle_arrays

    fused = VehicleSender(rig.publisher, "veh02", ["lidar"])
    fused.wait_matched()
    other = Sender(rig.publisher, "veh01", "lidar")  # nobody subscribes: no match to wait for
    other.tracks(TRACKS)
    fused.detections("lidar", detection_frame("veh02", "lidar", 1, TRACKS[:2], extrinsic=pose_at(0, 0, 0)))  # fmt: skip
    stamp = time.time_ns()
    fused.tracks("lidar", vehicle_arrays(TRACKS, [0.9, 0.8, 0.7], [[stamp]] * 3), ["ok"], stamp)

    def ready() -> bool:
        v = get_json(rig.view.url + "state.json")["vehicles"].get("veh02/@vehicle")
        return bool(v and v["sensors"][0]["detections"])

    wait_for(ready, 10, "the fused vehicle and its sensor's detections")
    got = get_json(rig.view.url + "state.json")
    assert got["sensors"].keys() == {"veh02/lidar"}  # its detections; no other vehicle
    vehicle = got["vehicles"]["veh02/@vehicle"]
    assert [t["id"] for t in vehicle["tracks"]] == [11, 12, 13]
    assert len(vehicle["sensors"][0]["detections"]["boxes"]) == 2
