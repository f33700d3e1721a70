"""The vehicle view drawn by a real headless browser: each fused track in its state's colour at
the pixel its position maps to, each fused sensor's detections (sent in the sensor's frame
with its extrinsic) outlined in that sensor's colour where the service puts them, and the
panel naming each sensor's condition."""

from __future__ import annotations

import re
import time
from pathlib import Path

import pytest

from simpletrack.view import Fov
from simpletrack.view.vehicle import SENSOR_COLOURS
from simpletrack.wire import WireTrackState
from tests.service_helpers import wait_for
from tests.view.browser import WINDOW, dump_dom, need_chromium, screenshot
from tests.view.conftest import Rig
from tests.view.frames import (
    Known,
    VehicleSender,
    detection_frame,
    in_sensor_frame,
    pose_at,
    vehicle_arrays,
)
from tests.view.test_page import BACKGROUND, COLOUR, close
from tests.view.test_state import get_json

pytestmark = [pytest.mark.zenoh, pytest.mark.browser]

X0, Y0, SCALE = 10.0, 0.0, 10.0  # the view window of the URL (the vehicle's frame)
SENSORS = ["lidar", "camera"]
LIDAR, CAMERA = pose_at(0.5, -0.2, 0.0, 1.8), pose_at(1.6, 0.4, 0.3, 1.4)  # sensor -> vehicle
VIEW = {"detections": True, "fov": {"lidar": Fov(360.0, 20.0), "camera": Fov(90.0, 40.0)}}

TRACKS = [
    Known(1, 25.0, 8.0, 4.5, 2.0, 0.3, WireTrackState.CONFIRMED),
    Known(2, 5.0, -12.0, 4.5, 2.0, -0.6, WireTrackState.TENTATIVE),
    Known(3, 35.0, -18.0, 4.5, 2.0, 1.4, WireTrackState.COASTING),
]
# One box each sensor sees alone, axis-aligned in the vehicle frame: its right edge falls on
# the middle of a pixel column, so a pixel there is wholly the outline's colour.
LIDAR_ONLY = Known(8, -5.05, 15.0, 4.0, 4.0, 0.0, WireTrackState.CONFIRMED)
CAMERA_ONLY = Known(9, 16.95, 20.0, 4.0, 4.0, 0.0, WireTrackState.CONFIRMED)


def to_px(x: float, y: float) -> tuple[float, float]:
    return WINDOW[0] / 2 + (x - X0) * SCALE, WINDOW[1] / 2 - (y - Y0) * SCALE


def rgb(hex_colour: str) -> tuple[int, int, int]:
    n = int(hex_colour[1:], 16)
    return n >> 16, (n >> 8) & 255, n & 255


def publish(rig: Rig) -> None:
    fused = VehicleSender(rig.publisher, "veh02", SENSORS)
    fused.wait_matched()
    stamp = time.time_ns()
    for sensor, mount, extra in (("lidar", LIDAR, LIDAR_ONLY), ("camera", CAMERA, CAMERA_ONLY)):
        local = [in_sensor_frame(t, mount) for t in [*TRACKS, extra]]
        fused.detections(sensor, detection_frame("veh02", sensor, 4, local, extrinsic=mount))
    stamps = [[stamp, stamp - 10**8], [stamp - 2 * 10**8, -1], [-1, stamp - 10**8]]
    columns = vehicle_arrays(TRACKS, [0.95, 0.5, 0.7], stamps)
    fused.tracks("lidar", columns, ["ok", "probation"], stamp)
    # A sensor's own stream too: the page still opens on the fused vehicle.
    rig.sender("veh01", "lidar").tracks(TRACKS[:1])

    def ready() -> bool:
        got = get_json(rig.view.url + "state.json")
        fused = got["vehicles"].get("veh02/@vehicle")
        return "veh01/lidar" in got["sensors"] and bool(
            fused and all(s["detections"] for s in fused["sensors"])
        )

    wait_for(ready, 10, "the fused vehicle, its detections and the other sensor")


@pytest.mark.parametrize("rig", [VIEW], indirect=True)
def test_the_vehicle_view_draws_fused_tracks_and_each_sensor_in_its_colour(
    rig: Rig, tmp_path: Path
) -> None:
    need_chromium()
    from PIL import Image

    publish(rig)
    url = f"{rig.view.url}?sensor=veh02/@vehicle&x0={X0}&y0={Y0}&scale={SCALE}&live=0"
    image = Image.open(screenshot(url, tmp_path / "vehicle.png")).convert("RGB")
    assert image.size == WINDOW
    for t in TRACKS:
        px, py = to_px(t.x, t.y)
        got = image.getpixel((round(px), round(py)))
        assert close(got, COLOUR[t.id]), (t.id, got, COLOUR[t.id])
    # Each sensor's own box, moved by its extrinsic: its right edge in its sensor's colour.
    for box, colour in ((LIDAR_ONLY, SENSOR_COLOURS[0]), (CAMERA_ONLY, SENSOR_COLOURS[1])):
        px, py = to_px(box.x + box.l / 2, box.y)
        got = image.getpixel((int(px), round(py)))
        assert close(got, rgb(colour), 16), (box.id, got, colour)
        inside = image.getpixel((round(to_px(box.x, box.y)[0]), round(py)))
        assert not close(inside, rgb(colour), 40), (box.id, "an outline, not a fill", inside)
    assert SENSOR_COLOURS[0] != SENSOR_COLOURS[1]
    # Out of every field of view, box and label: background.
    px, py = to_px(45.0, 25.0)
    got = image.getpixel((round(px), round(py)))
    assert close(got, BACKGROUND), got


@pytest.mark.parametrize("rig", [VIEW], indirect=True)
def test_the_page_opens_on_the_fused_vehicle_and_names_each_sensor_condition(
    rig: Rig, tmp_path: Path
) -> None:
    need_chromium()
    publish(rig)
    dom = dump_dom(f"{rig.view.url}?live=0", tmp_path)
    assert re.search(r'<tr id="source-row">\s*<td>source</td><td id="source">lidar #1</td>', dom)
    rows = dict(re.findall(r'<tr data-sensor="(\w+)">.*?class="st-(\w+)"', dom))
    assert rows == {"lidar": "ok", "camera": "probation"}
    assert "veh02/@vehicle (fused)" in dom
    for name in SENSORS:
        assert f"{name}: detections, field of view" in dom
