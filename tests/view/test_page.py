"""The page drawn by a real headless browser matches what was published: each box's centre
has its state's colour at the pixel the URL's view window maps it to, the rest is background."""

from __future__ import annotations

from pathlib import Path

import pytest

from simpletrack.wire import WireTrackState
from tests.service_helpers import wait_for
from tests.view.browser import WINDOW, need_chromium, screenshot
from tests.view.conftest import Rig
from tests.view.frames import Known
from tests.view.test_state import state

pytestmark = [pytest.mark.zenoh, pytest.mark.browser]

# The page's fill colours (page.html STYLE) and background.
CONFIRMED, TENTATIVE, COASTING = (0x2E, 0xA0, 0x43), (0xB0, 0x7D, 0x12), (0x3B, 0x5D, 0x8F)
BACKGROUND = (0x14, 0x17, 0x1C)
X0, Y0, SCALE = 20.0, 0.0, 10.0  # the view window of the URL

TRACKS = [
    Known(1, 30.0, 10.0, 4.5, 2.0, 0.3, WireTrackState.CONFIRMED),
    Known(2, 10.0, -10.0, 4.5, 2.0, -0.6, WireTrackState.TENTATIVE),
    Known(3, 35.0, -15.0, 4.5, 2.0, 1.4, WireTrackState.COASTING),
]
COLOUR = {1: CONFIRMED, 2: TENTATIVE, 3: COASTING}


def to_px(x: float, y: float) -> tuple[int, int]:
    """The page's documented world->pixel mapping for ?x0=&y0=&scale=."""
    return round(WINDOW[0] / 2 + (x - X0) * SCALE), round(WINDOW[1] / 2 - (y - Y0) * SCALE)


def close(a: tuple[int, ...], b: tuple[int, ...], tol: int = 12) -> bool:
    return all(abs(p - q) <= tol for p, q in zip(a[:3], b[:3], strict=True))


def test_the_page_draws_each_track_where_and_how_it_was_published(rig: Rig, tmp_path: Path) -> None:
    need_chromium()
    from PIL import Image

    rig.sender("veh01", "lidar").tracks(TRACKS)
    # Another sensor's track, where the chosen sensor has nothing: it must not be drawn.
    rig.sender("veh02", "front").tracks([Known(9, 45.0, 5.0, 4.5, 2.0, 0.0, 1)])
    wait_for(lambda: len(state(rig)) == 2, 10, "both sensors")
    url = f"{rig.view.url}?sensor=veh01/lidar&x0={X0}&y0={Y0}&scale={SCALE}&live=0"
    image = Image.open(screenshot(url, tmp_path / "view.png")).convert("RGB")
    assert image.size == WINDOW
    for t in TRACKS:
        px = image.getpixel(to_px(t.x, t.y))
        assert close(px, COLOUR[t.id]), (t.id, px, COLOUR[t.id])
    # Between boxes and grid lines (every 10 m here, on whole multiples): background.
    for x, y in [(25.0, 5.0), (45.0, 5.0), (15.0, -15.0), (35.0, 15.0), (5.0, -5.0)]:
        px = image.getpixel(to_px(x, y))
        assert close(px, BACKGROUND), ((x, y), px)
