"""A vehicle that restarts its publisher (seq from 0 again, a new session id) is tracked from
its first frame, keeps its track ids when its clock went on, and can resume its seq."""

from __future__ import annotations

import time
from collections.abc import Iterator
from pathlib import Path

import pytest

from simpletrack.client import DetectionPublisher
from tests.faults.vehicle import last_ids, vehicle_options
from tests.service_helpers import Client, ServiceProcess, moving_cars, start_service, wait_for


@pytest.fixture(scope="module")
def service(tmp_path_factory: pytest.TempPathFactory) -> Iterator[ServiceProcess]:
    svc = start_service(tmp_path_factory.mktemp("reboot"), instance="svc-reboot")
    yield svc
    svc.stop()


@pytest.fixture
def cli(service: ServiceProcess) -> Iterator[Client]:
    c = Client(service.endpoint)
    yield c
    c.close()


def _publisher(service: ServiceProcess, vehicle: str) -> DetectionPublisher:
    pub = DetectionPublisher.connect(
        vehicle, "lidar", classes=("Car",), options=vehicle_options(service.endpoint)
    )
    assert pub.wait_for_service(10)
    return pub


def _stream(pub: DetectionPublisher, first_k: int, n: int, clock_offset_ns: int = 0) -> None:
    for k in range(first_k, first_k + n):
        pub.publish(moving_cars(k), stamp_ns=time.time_ns() + clock_offset_ns)
        time.sleep(0.1)


def test_a_restarted_publisher_is_tracked_from_its_first_frame_and_keeps_the_ids(
    service: ServiceProcess, cli: Client
) -> None:
    sensor = "car-20/lidar"
    first = _publisher(service, "car-20")
    _stream(first, 0, 10)
    wait_for(lambda: cli.received.n_tracks(sensor) == 10, 20, "10 frames of the first run")
    ids = last_ids(cli.received, sensor)
    first.close()

    second = _publisher(service, "car-20")  # seq starts again at 0, later stamps
    assert second.next_seq == 0 and second.session_id != first.session_id
    _stream(second, 12, 3)
    wait_for(lambda: cli.received.n_tracks(sensor) == 13, 20, "every frame of the second run")
    assert [f.seq for f, _ in cli.received.tracks[sensor][10:]] == [0, 1, 2]
    assert last_ids(cli.received, sensor) == ids
    assert list(second.errors(timeout=0.3)) == [] and cli.received.n_errors(sensor) == 0
    second.close()


def test_a_publisher_rebooted_with_its_clock_set_back_is_tracked_at_once(
    service: ServiceProcess, cli: Client
) -> None:
    sensor = "car-21/lidar"
    first = _publisher(service, "car-21")
    _stream(first, 0, 5)
    first.close()
    second = _publisher(service, "car-21")
    _stream(second, 0, 3, clock_offset_ns=-2_000_000_000)  # 2 s back: under reset_backward_s
    wait_for(lambda: cli.received.n_tracks(sensor) == 8, 20, "every frame of both runs")
    assert cli.received.n_errors(sensor) == 0
    second.close()


def test_a_restarted_publisher_resumes_after_the_last_seq_the_service_processed(
    service: ServiceProcess, cli: Client, tmp_path: Path
) -> None:
    sensor = "car-22/lidar"
    first = _publisher(service, "car-22")
    _stream(first, 0, 7)
    wait_for(lambda: cli.received.n_tracks(sensor) == 7, 20, "7 frames")
    first.close()
    second = _publisher(service, "car-22")
    assert second.resume(timeout=5) == 6
    assert second.publish(moving_cars(8)) == 7
    wait_for(lambda: cli.received.n_tracks(sensor) == 8, 20, "the resumed frame")
    assert cli.received.tracks[sensor][-1][0].seq == 7
    nobody = _publisher(service, "car-23")
    assert nobody.resume(timeout=2) is None and nobody.next_seq == 0
    for p in (second, nobody):
        p.close()
