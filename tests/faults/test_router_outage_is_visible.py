"""Item 6: a router outage is visible. Service and vehicle are clients of a router process;
the router is killed with SIGKILL: /readyz turns 503 and the router metric drops within a
bound, the vehicle library reports the frames it cannot deliver, and once the router is back
the service is ready again (within Zenoh's reconnect period, no 4 s back-off)."""

from __future__ import annotations

import time
from collections.abc import Iterator
from pathlib import Path

import pytest

from simpletrack.client import DetectionPublisher, Undelivered, ZenohOptions
from tests.faults.router_process import Router, new_router, start_client_service
from tests.service_helpers import ServiceProcess, metric, moving_cars, stamp, wait_for

pytestmark = pytest.mark.zenoh

VISIBLE_WITHIN_S = 1.5  # a killed router's TCP connection resets at once
READY_AGAIN_WITHIN_S = 4.0  # router start-up plus at most one reconnect_max_ms (1 s)


@pytest.fixture
def router() -> Iterator[Router]:
    r = new_router().start()
    yield r
    r.stop()


@pytest.fixture
def service(tmp_path: Path, router: Router) -> Iterator[ServiceProcess]:
    svc = start_client_service(tmp_path, router.endpoint, instance="outage-visible")
    wait_for(lambda: svc.http("/readyz")[0] == 200, 30, "the service ready through the router")
    yield svc
    svc.stop()


def test_a_killed_router_makes_the_service_unready_and_the_vehicle_report_undelivered_frames(
    router: Router, service: ServiceProcess
) -> None:
    undelivered: list[Undelivered] = []
    options = ZenohOptions(mode="client", connect=[router.endpoint])
    with DetectionPublisher.connect(
        "veh-out", "lidar", classes=("Car",), options=options, on_undelivered=undelivered.append
    ) as pub:
        assert pub.wait_for_service(10)
        for k in range(3):
            pub.publish(moving_cars(k), stamp_ns=stamp(k))
        assert undelivered == [] and pub.delivering
        assert metric(service.metrics(), "simpletrack_zenoh_routers") == 1

        router.kill()
        killed = time.monotonic()
        wait_for(lambda: service.http("/readyz")[0] == 503, VISIBLE_WITHIN_S, "/readyz 503")
        values = service.metrics()
        assert metric(values, "simpletrack_zenoh_routers") == 0
        assert metric(values, "simpletrack_zenoh_router_disconnects_total") == 1
        wait_for(lambda: not pub.delivering, VISIBLE_WITHIN_S - (time.monotonic() - killed))

        seqs = [pub.publish(moving_cars(k), stamp_ns=stamp(k)) for k in range(3, 6)]
        assert undelivered == [Undelivered(s, lost=False) for s in seqs]
        assert pub.held == 3 and pub.lost == 0

        router.start()
        back = time.monotonic()
        wait_for(lambda: service.http("/readyz")[0] == 200, READY_AGAIN_WITHIN_S, "ready again")
        assert metric(service.metrics(), "simpletrack_zenoh_routers") == 1
        wait_for(lambda: pub.delivering, READY_AGAIN_WITHIN_S - (time.monotonic() - back))
    events = [e.get("event") for e in service.logs()]
    assert "router_lost" in events and events.count("router_connected") >= 2


def test_an_outage_longer_than_the_cache_reports_the_frames_pushed_out_as_lost(
    router: Router, service: ServiceProcess
) -> None:
    undelivered: list[Undelivered] = []
    options = ZenohOptions(mode="client", connect=[router.endpoint])
    with DetectionPublisher.connect(
        "veh-lost",
        "lidar",
        classes=("Car",),
        options=options,
        cache_frames=2,
        on_undelivered=undelivered.append,
    ) as pub:
        assert pub.wait_for_service(10)
        router.kill()
        wait_for(lambda: not pub.delivering, VISIBLE_WITHIN_S, "the vehicle to see the outage")
        for k in range(5):
            pub.publish(moving_cars(k), stamp_ns=stamp(k))
    lost = [u.seq for u in undelivered if u.lost]
    assert lost == [0, 1, 2] and pub.held == 5 and pub.lost == 3
