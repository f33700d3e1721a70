"""A fused vehicle taken over from its snapshot (a failover, a hand-off, a restart) starts a
new reorder buffer: the sensors the state had live are waited for as they were, so a camera
frame that reaches the taker first is not let go ahead of the lidar's stamped before it
(once in CI, such a camera frame was judged against stale tracks and flagged for its
clock). A sensor silent or kept out at the snapshot is not waited for."""

from __future__ import annotations

import time

import pytest

from simpletrack.core.tracker import Tracker
from simpletrack.core.vehicle import Condition
from simpletrack.server.sensors import Arrival
from simpletrack.server.vehicles import new_vehicle, vehicle_from_snapshot
from tests.core.fusion_helpers import fusion, tracker_config


@pytest.mark.parametrize(
    ("lidar", "waited"),
    [(Condition.OK, True), (Condition.SILENT, False), (Condition.CLOCK, False)],
)
def test_the_taker_waits_for_the_sensors_the_state_had_live(lidar: Condition, waited: bool) -> None:
    config, fused = tracker_config(), fusion()
    state = new_vehicle("veh01", config, fused, "d", window_s=0.3, silent_after_s=1.0)
    state.tracker.records["lidar"].condition = lidar
    state.tracker.records["camera"].condition = Condition.OK
    state.taken = {
        "lidar": Arrival(27, 2_700, None, None),
        "camera": Arrival(18, 2_750, None, None),
    }
    state.last = state.taken["camera"]
    snap = state.snapshot(state_format=2)

    taker = vehicle_from_snapshot(snap, config, fused, "d", lambda: Tracker(config))
    now = time.monotonic()
    taker.buffer.push("camera", 19, 2_900, "camera 19", now)  # type: ignore[arg-type]
    if not waited:
        assert taker.buffer.pop_ready(now) == ["camera 19"]
        return
    assert taker.buffer.pop_ready(now) == []
    taker.buffer.push("lidar", 28, 2_800, "lidar 28", now)  # type: ignore[arg-type]
    assert taker.buffer.pop_ready(now) == ["lidar 28"]
    assert taker.buffer.pop_ready(now + 0.3) == ["camera 19"]  # the window
