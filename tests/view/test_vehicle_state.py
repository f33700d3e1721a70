"""The vehicle view's state, without Zenoh or a browser: a fused vehicle's frame as JSON, its
sensors' detections moved as the service moves them (pose, else extrinsic; the core's own
``transform_boxes`` is the reference), their placements, and which sensors last updated each
track."""

from __future__ import annotations

import math
from typing import Any

import numpy as np
import pytest

from simpletrack.core.boxes import Boxes, transform_boxes
from simpletrack.view import Fov, ViewState
from simpletrack.view.state import default_stream
from simpletrack.view.vehicle import SENSOR_COLOURS, contributors_json
from simpletrack.wire import SensorCondition, WireTrackState
from tests.view.frames import (
    Known,
    detection_frame,
    in_sensor_frame,
    pose_at,
    vehicle_arrays,
    vehicle_frame,
    vehicle_message,
)

T0 = 1_700_000_000_000_000_000
MS = 1_000_000
SENSORS = ["lidar", "camera"]
LIDAR, CAMERA = pose_at(0.5, -0.2, 0.0, 1.8), pose_at(1.6, 0.4, 0.3, 1.4)  # sensor -> vehicle
TRACKS = [
    Known(1, 20.0, 3.0, 4.5, 2.0, 0.2, WireTrackState.CONFIRMED),
    Known(2, -10.0, -4.0, 4.5, 2.0, 1.0, WireTrackState.TENTATIVE),
]


def fused(
    seq: int,
    stamp: int,
    source: str,
    stamps: list[list[int]],
    states: tuple[str, str] = ("ok", "ok"),
    pose: list[float] | None = None,
) -> Any:
    columns = vehicle_arrays(TRACKS, [0.9, 0.4], stamps)
    return vehicle_message(
        vehicle_frame("veh01", seq, stamp, source, SENSORS, list(states), columns, pose)
    )


def view() -> ViewState:
    return ViewState({"lidar": Fov(360.0, 50.0), "veh01/camera": Fov(90.0, 75.0)}, True)


def boxes_at(got: dict[str, Any]) -> list[tuple[float, float, float]]:
    return [(b["x"], b["y"], b["yaw"]) for b in got["detections"]["boxes"]]


def test_a_vehicle_tracked_in_its_own_frame_draws_each_sensor_through_its_extrinsic() -> None:
    state = view()
    state.add_vehicle_tracks(fused(1, T0, "lidar", [[T0, -1], [T0, -1]]))
    for seq, (sensor, mount) in enumerate((("lidar", LIDAR), ("camera", CAMERA))):
        local = [in_sensor_frame(t, mount) for t in TRACKS]
        state.add_detections(
            f"veh01/{sensor}", detection_frame("veh01", sensor, seq, local, extrinsic=mount), 5
        )
    got = state.event_json(None)
    assert got["names"] == ["veh01/@vehicle", "veh01/camera", "veh01/lidar"]
    frame = got["frame"]
    assert frame["kind"] == "vehicle" and frame["name"] == "veh01/@vehicle"
    assert frame["source"] == {"sensor": "lidar", "seq": 1}
    assert frame["ego"] == {"x": 0.0, "y": 0.0, "yaw": 0.0}  # the vehicle frame's origin
    lidar, camera = frame["sensors"]
    assert [lidar["name"], camera["name"]] == SENSORS
    assert [lidar["colour"], camera["colour"]] == list(SENSOR_COLOURS[:2])
    assert lidar["fov"] == {"deg": 360.0, "range": 50.0}  # by sensor name
    assert camera["fov"] == {"deg": 90.0, "range": 75.0}  # by vehicle/sensor
    assert camera["mount"] == {"x": 1.6, "y": 0.4, "yaw": 0.3}
    assert camera["mount_from"] == "detections" and lidar["mount"]["x"] == 0.5
    for s in (lidar, camera):  # both back where the tracks are
        for (x, y, yaw), t in zip(boxes_at(s), TRACKS, strict=True):
            assert (x, y) == (pytest.approx(t.x, abs=1e-3), pytest.approx(t.y, abs=1e-3))
            assert math.remainder(yaw - t.yaw, 2 * math.pi) == pytest.approx(0, abs=1e-3)
    assert [t["existence"] for t in frame["tracks"]] == [0.9, 0.4]
    assert state.state_json()["vehicles"].keys() == {"veh01/@vehicle"}
    assert state.state_json()["sensors"].keys() == {"veh01/camera", "veh01/lidar"}


def test_boxes_move_as_the_core_moves_them_a_tilted_pose_included() -> None:
    """A pose with pitch and roll: the centre's height moves x and y as in the service."""
    rot = _rotation(yaw=0.7, pitch=0.05, roll=-0.04)
    pose = np.eye(4)
    pose[:3, :3], pose[:3, 3] = rot, (100.0, -40.0, 2.0)
    state = view()
    state.add_vehicle_tracks(fused(1, T0, "lidar", [[T0, -1], [T0, -1]], pose=pose_at(0, 0, 0)))
    frame = detection_frame("veh01", "lidar", 1, TRACKS, pose=list(pose.ravel()))
    state.add_detections("veh01/lidar", frame, 5)
    got = state.vehicle_json("veh01/@vehicle")
    assert got is not None
    params = np.array([[t.x, t.y, 0.8, t.yaw, t.l, t.w, 1.6] for t in TRACKS], np.float64)
    core = transform_boxes(Boxes(params, np.full(2, 0.9), np.zeros(2, np.int64)), pose).params
    for (x, y, yaw), want in zip(boxes_at(got["sensors"][0]), core, strict=True):
        assert (x, y) == (pytest.approx(want[0], abs=2e-3), pytest.approx(want[1], abs=2e-3))
        assert math.remainder(yaw - want[3], 2 * math.pi) == pytest.approx(0, abs=1e-3)


def _rotation(yaw: float, pitch: float, roll: float) -> Any:
    cy, sy, cp, sp, cr, sr = (f(a) for a in (yaw, pitch, roll) for f in (math.cos, math.sin))
    rz = np.array([[cy, -sy, 0], [sy, cy, 0], [0, 0, 1]])
    ry = np.array([[cp, 0, sp], [0, 1, 0], [-sp, 0, cp]])
    rx = np.array([[1, 0, 0], [0, cr, -sr], [0, sr, cr]])
    return rz @ ry @ rx


def test_in_the_world_frame_the_pose_wins_and_the_ego_is_pose_times_inverse_extrinsic() -> None:
    vehicle = pose_at(200.0, 50.0, 1.0)  # vehicle -> world
    cam = (np.array(vehicle).reshape(4, 4) @ np.array(CAMERA).reshape(4, 4)).ravel().tolist()
    state = view()
    state.add_vehicle_tracks(fused(1, T0, "camera", [[-1, T0], [-1, T0]], pose=cam))
    world = [Known(t.id, 200.0 + t.x, 50.0 + t.y, t.l, t.w, t.yaw, t.state) for t in TRACKS]
    local = [in_sensor_frame(t, cam) for t in world]
    state.add_detections(
        "veh01/camera", detection_frame("veh01", "camera", 1, local, pose=cam, extrinsic=CAMERA), 5
    )
    got = state.vehicle_json("veh01/@vehicle")
    assert got is not None
    for (x, y, _), t in zip(boxes_at(got["sensors"][1]), world, strict=True):
        assert (x, y) == (pytest.approx(t.x, abs=1e-3), pytest.approx(t.y, abs=1e-3))
    assert got["ego"] == {"x": 200.0, "y": 50.0, "yaw": 1.0}
    assert got["ego_from"] == "camera pose and extrinsic"
    mount = got["sensors"][1]["mount"]
    c, s = math.cos(1.0), math.sin(1.0)
    assert mount["x"] == pytest.approx(200.0 + 1.6 * c - 0.4 * s, abs=1e-3)
    assert mount["y"] == pytest.approx(50.0 + 1.6 * s + 0.4 * c, abs=1e-3)
    assert mount["yaw"] == pytest.approx(1.3, abs=1e-4)
    # The lidar sent nothing: no placement, no wedge.
    assert got["sensors"][0]["mount"] is None and got["sensors"][0]["mount_from"] is None


def test_frames_the_service_refuses_are_not_drawn() -> None:
    """An extrinsic alone for a vehicle tracked in the world frame, a pose for one tracked in
    its own: the service refuses both (server/fused.py), so they are not drawn."""
    state = view()
    state.add_vehicle_tracks(fused(1, T0, "lidar", [[T0, -1], [T0, -1]], pose=pose_at(0, 0, 0)))
    state.add_detections("veh01/camera", detection_frame("veh01", "camera", 1, TRACKS, extrinsic=CAMERA), 5)  # fmt: skip
    camera = _sensor(state, "camera")
    assert camera["detections"] is None and "refused" in camera["detections_skipped"]

    state = view()
    state.add_vehicle_tracks(fused(1, T0, "lidar", [[T0, -1], [T0, -1]]))
    state.add_detections("veh01/camera", detection_frame("veh01", "camera", 1, TRACKS, pose=CAMERA), 5)  # fmt: skip
    camera = _sensor(state, "camera")
    assert camera["detections"] is None and "refused" in camera["detections_skipped"]
    # Its mounting unknown: the wedge at the vehicle's origin, said so.
    assert camera["mount"] == {"x": 0.0, "y": 0.0, "yaw": 0.0}
    assert camera["mount_from"] == "assumed"


def _sensor(state: ViewState, name: str) -> dict[str, Any]:
    got = state.vehicle_json("veh01/@vehicle")
    assert got is not None
    return next(s for s in got["sensors"] if s["name"] == name)


def test_without_detections_a_sensor_is_placed_at_the_pose_its_messages_echo() -> None:
    state = ViewState({"lidar": Fov(360.0, 50.0)}, detections=False)
    state.add_vehicle_tracks(fused(1, T0, "camera", [[-1, T0], [-1, T0]], pose=pose_at(5, 6, 0.5)))
    state.add_vehicle_tracks(fused(2, T0 + 50 * MS, "lidar", [[T0 + 50 * MS, T0], [-1, T0]], pose=pose_at(4, 6, 0.4)))  # fmt: skip
    got = state.vehicle_json("veh01/@vehicle")
    assert got is not None
    lidar, camera = got["sensors"]
    assert camera["mount"] == {"x": 5.0, "y": 6.0, "yaw": 0.5} and camera["mount_from"] == "tracks"
    assert lidar["mount"] == {"x": 4.0, "y": 6.0, "yaw": 0.4}
    assert got["ego"] == lidar["mount"] and got["ego_from"] == "lidar pose"
    assert [lidar["applied_stamp_ns"], camera["applied_stamp_ns"]] == [T0 + 50 * MS, T0]
    assert camera["detections"] is None and camera["detections_skipped"] is None


def test_a_contributor_is_fresh_when_its_sensor_latest_frame_updated_the_track() -> None:
    state = view()
    state.add_vehicle_tracks(fused(1, T0, "lidar", [[T0, -1], [T0, -1]]))
    state.add_vehicle_tracks(fused(2, T0 + 40 * MS, "camera", [[T0, T0 + 40 * MS], [T0, -1]]))
    # The lidar's next frame updates track 1 only; the camera's latest updated track 1.
    stamps = [[T0 + 100 * MS, T0 + 40 * MS], [T0, -1]]
    state.add_vehicle_tracks(fused(3, T0 + 100 * MS, "lidar", stamps))
    got = state.vehicle_json("veh01/@vehicle")
    assert got is not None
    one, two = got["tracks"]
    assert one["contributors"] == [
        {"sensor": "lidar", "stamp_ns": T0 + 100 * MS, "age_s": 0.0, "fresh": True},
        {"sensor": "camera", "stamp_ns": T0 + 40 * MS, "age_s": 0.06, "fresh": True},
    ]
    assert two["contributors"] == [
        {"sensor": "lidar", "stamp_ns": T0, "age_s": 0.1, "fresh": False},  # missed since
    ]
    # The camera silent: its updates are old news, however recent its last frame.
    state.add_vehicle_tracks(fused(4, T0 + 100 * MS, "lidar", stamps, states=("ok", "silent")))
    got = state.vehicle_json("veh01/@vehicle")
    assert got is not None
    assert [c["fresh"] for c in got["tracks"][0]["contributors"]] == [True, False]
    assert [s["state"] for s in got["sensors"]] == ["ok", "silent"]
    assert got["stats"]["frames"] == 4 and got["stats"]["tracks"] == 2


def test_contributors_of_a_sensor_whose_messages_the_view_never_saw_are_fresh() -> None:
    ok = SensorCondition.OK
    got = contributors_json(["a", "b"], [ok, ok], [10, -1], 30, {})
    assert got == [{"sensor": "a", "stamp_ns": 10, "age_s": 0.0, "fresh": True}]


def test_a_page_naming_nothing_opens_on_the_first_fused_vehicle() -> None:
    assert default_stream(["veh01/lidar", "veh02/@vehicle", "veh03/@vehicle"]) == "veh02/@vehicle"
    assert default_stream(["veh01/lidar", "veh01/radar"]) == "veh01/lidar"
    assert default_stream([]) is None
    state = view()
    state.add_vehicle_tracks(fused(1, T0, "lidar", [[T0, -1], [T0, -1]]))
    assert state.event_json("veh01/nothing")["frame"]["name"] == "veh01/@vehicle"
    assert state.sensor_json("veh09/@vehicle") is None
