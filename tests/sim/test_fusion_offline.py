"""The offline fused fleet (sim/fusion_offline.py): the sweep and the sensor ablation use it."""

from __future__ import annotations

from simpletrack.sim.demo_tracker import DEMO_FUSION
from simpletrack.sim.fusion_offline import what_each_sensor_adds


def test_each_sensor_alone_with_the_demos_settings() -> None:
    rows = dict(what_each_sensor_adds(seed=3, ticks=90))
    assert list(rows) == ["lidar + camera", "lidar", "camera"]
    both, lidar, camera = rows.values()
    assert both.gt == lidar.gt == camera.gt > 0  # the same truth for every row
    assert lidar.tp > 0 and both.tp > 0
    # The demo's camera may not start tracks: alone, it reports nothing.
    assert DEMO_FUSION["camera_spawn"] is False
    assert camera.tp == camera.fp == 0 and camera.fn == camera.gt
