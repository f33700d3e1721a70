"""Item 6 (its bound): the vehicle's cache serves recovery after an outage, not replay. A
service that first hears of a vehicle already streaming takes only the latest
``history_frames`` frames of its cache (default 1), so a (re)started service does not track
seconds-old frames again."""

from __future__ import annotations

import time
from pathlib import Path

import pytest

from simpletrack.client import DetectionPublisher, ZenohOptions
from tests.faults.router_process import new_router, start_client_service
from tests.service_helpers import Client, moving_cars, stamp, wait_for

pytestmark = pytest.mark.zenoh


def test_a_service_started_after_the_vehicle_takes_only_its_latest_cached_frame(
    tmp_path: Path,
) -> None:
    router = new_router().start()
    options = ZenohOptions(mode="client", connect=[router.endpoint])
    planner = Client(router.endpoint)
    svc = None
    try:
        with DetectionPublisher.connect(
            "veh-new", "lidar", classes=("Car",), options=options
        ) as pub:
            for k in range(20):
                pub.publish(moving_cars(k), stamp_ns=stamp(k))
            svc = start_client_service(tmp_path, router.endpoint, instance="late-service")
            wait_for(lambda: svc.http("/readyz")[0] == 200, 30, "the service ready")
            wait_for(lambda: planner.received.n_tracks("veh-new/lidar") >= 1, 10, "the latest")
            time.sleep(1.0)  # several heartbeats: nothing older may follow
            for k in range(20, 23):
                pub.publish(moving_cars(k), stamp_ns=stamp(k))
            wait_for(lambda: planner.received.n_tracks("veh-new/lidar") >= 4, 10, "live frames")
        with planner.received.lock:
            seqs = [frame.seq for frame, _ in planner.received.tracks["veh-new/lidar"]]
        assert seqs == [19, 20, 21, 22]
    finally:
        planner.close()
        if svc is not None:
            svc.stop()
        router.stop()
