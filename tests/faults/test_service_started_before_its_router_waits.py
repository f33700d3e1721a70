"""Item 6: a service started before its router waits for it, not ready, instead of exiting;
it becomes ready and tracks once the router is up. Told not to wait, it exits as Zenoh does;
SIGTERM while it waits stops it cleanly."""

from __future__ import annotations

import signal
import time
from pathlib import Path

import pytest

from tests.faults.router_process import new_router, start_client_service
from tests.service_helpers import client, metric, moving_cars, stamp, wait_for

pytestmark = pytest.mark.zenoh


def test_a_service_started_before_its_router_waits_unready_then_tracks(tmp_path: Path) -> None:
    router = new_router()
    svc = start_client_service(tmp_path, router.endpoint, instance="early")
    try:
        time.sleep(2.0)  # several connect attempts fail meanwhile
        assert svc.proc.poll() is None, svc.log_path.read_text()
        assert svc.http("/healthz")[0] == 200
        assert svc.http("/readyz")[0] == 503
        assert metric(svc.metrics(), "simpletrack_zenoh_routers") == 0
        router.start()
        wait_for(lambda: svc.http("/readyz")[0] == 200, 5, "ready once the router is up")
        assert metric(svc.metrics(), "simpletrack_zenoh_routers") == 1
        with client(router.endpoint) as c:
            c.send("veh-early", "lidar", 0, stamp(0), moving_cars(0))
            wait_for(lambda: c.received.n_tracks("veh-early/lidar") == 1, 10, "tracks")
        assert svc.stop() == 0
        events = [e.get("event") for e in svc.logs()]
        assert events.index("waiting_for_router") < events.index("service_started")
    finally:
        svc.stop(signal.SIGKILL)
        router.stop()


def test_a_service_told_not_to_wait_exits_without_its_router(tmp_path: Path) -> None:
    router = new_router()
    svc = start_client_service(
        tmp_path, router.endpoint, env={"SIMPLETRACK_WAIT_FOR_ROUTER": "false"}, instance="nowait"
    )
    try:
        assert svc.proc.wait(30) != 0
    finally:
        svc.stop(signal.SIGKILL)


def test_sigterm_stops_a_service_waiting_for_its_router(tmp_path: Path) -> None:
    router = new_router()
    svc = start_client_service(tmp_path, router.endpoint, instance="waiting")
    wait_for(lambda: "waiting_for_router" in svc.log_path.read_text(), 30, "waiting")
    started = time.monotonic()
    assert svc.stop(signal.SIGTERM, timeout=10) == 0
    assert time.monotonic() - started < 3.0
