"""Service and vehicle are clients of a Zenoh router (a Python session in router mode in a
subprocess). The router is killed and restarted after ~3 s while the vehicle streams in real
time: the tracks keep their ids."""

from __future__ import annotations

import signal
import time
from pathlib import Path

from simpletrack.client import DetectionPublisher
from simpletrack.session import open_session
from simpletrack.spawn import free_port
from tests.faults.vehicle import (
    RealTimeVehicle,
    ids_since,
    last_ids,
    start_router,
    start_service_via_router,
    vehicle_options,
)
from tests.service_helpers import Received, metric, wait_for

SENSOR = "car-50/lidar"


def test_ids_survive_a_three_second_router_outage(tmp_path: Path) -> None:
    port = free_port()
    endpoint = f"tcp/127.0.0.1:{port}"
    router = start_router(port)
    svc = None
    planner = None
    vehicle = None
    try:
        svc = start_service_via_router(tmp_path, endpoint)
        planner = open_session(vehicle_options(endpoint, mode="client"))
        received = Received()
        sub = planner.declare_subscriber("fleet/*/*/tracks", received.on_tracks)
        pub = DetectionPublisher.connect(
            "car-50", "lidar", classes=("Car",), options=vehicle_options(endpoint, "client")
        )
        assert pub.wait_for_service(10)
        vehicle = RealTimeVehicle(pub)
        vehicle.start()
        wait_for(lambda: received.n_tracks(SENSOR) >= 30, 30, "3 s of tracks")
        ids = last_ids(received, SENSOR)
        assert len(ids) == 3
        router.send_signal(signal.SIGKILL)
        router.wait()
        down_ns = time.time_ns()
        time.sleep(3.0)
        router = start_router(port)
        wait_for(lambda: len(ids_since(received, SENSOR, down_ns)) >= 10, 60, "frames after")
        after = ids_since(received, SENSOR, down_ns)
        assert after[0] == ids and after[-1] == ids, after
        assert metric(svc.metrics(), "simpletrack_tracker_resets_total", reason="gap") == 0
        sub.undeclare()
    finally:
        if vehicle is not None:
            vehicle.stop()
        if planner is not None:
            planner.close()  # type: ignore[no-untyped-call]
        if svc is not None:
            svc.stop()
        router.send_signal(signal.SIGTERM)
        router.wait(10)
