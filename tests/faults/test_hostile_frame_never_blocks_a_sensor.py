"""One bad or hostile frame on a sensor's key (a spoofed seq 2^62, a stamp seconds or an hour
off, a stray session) never makes the sensor's later good frames fail, and where the wall
clock shows the bad frame was wrong the sensor keeps its track ids."""

from __future__ import annotations

import time
from collections.abc import Iterator

import pytest

from simpletrack.client import DetectionPublisher
from tests.faults.vehicle import last_ids, vehicle_options
from tests.service_helpers import Client, ServiceProcess, moving_cars, start_service, wait_for

S = 1_000_000_000
# (what the spoofed frame carries) seq, stamp offset from now, session id (None: the victim's)
HOSTILE = [
    pytest.param(2**62, 0, None, id="seq 2^62"),
    pytest.param(None, 3 * S, None, id="stamp 3 s ahead"),
    pytest.param(None, 3600 * S, None, id="stamp an hour ahead"),
    pytest.param(None, -3600 * S, None, id="stamp an hour behind"),
    pytest.param(0, -S // 20, 12345, id="another session, stamp a little behind"),
    pytest.param(0, S, 12345, id="another session, stamp a second ahead"),
    pytest.param("same", 0, None, id="the victim's next seq taken"),
]


@pytest.fixture(scope="module")
def service(tmp_path_factory: pytest.TempPathFactory) -> Iterator[ServiceProcess]:
    svc = start_service(tmp_path_factory.mktemp("hostile"), instance="svc-hostile")
    yield svc
    svc.stop()


@pytest.fixture
def cli(service: ServiceProcess) -> Iterator[Client]:
    c = Client(service.endpoint)
    yield c
    c.close()


@pytest.mark.parametrize(("seq", "offset_ns", "session"), HOSTILE)
def test_the_next_good_frames_are_tracked_with_their_ids(
    service: ServiceProcess,
    cli: Client,
    seq: int | str | None,
    offset_ns: int,
    session: int | None,
    request: pytest.FixtureRequest,
) -> None:
    vehicle = f"car-{abs(hash(request.node.callspec.id)) % 10**6}"
    sensor = f"{vehicle}/lidar"
    pub = DetectionPublisher.connect(
        vehicle, "lidar", classes=("Car",), options=vehicle_options(service.endpoint)
    )
    assert pub.wait_for_service(10)
    for k in range(8):
        pub.publish(moving_cars(k))
        time.sleep(0.1)
    wait_for(lambda: cli.received.n_tracks(sensor) == 8, 20, "8 good frames")
    ids = last_ids(cli.received, sensor)

    spoofed_seq = pub.next_seq if seq in (None, "same") else int(seq)  # type: ignore[arg-type]
    cli.send(
        vehicle,
        "lidar",
        seq=spoofed_seq,
        stamp_ns=time.time_ns() + offset_ns,
        boxes=moving_cars(8),
        session_id=pub.session_id if session is None else session,
    )
    time.sleep(0.1)
    good = [pub.publish(moving_cars(k)) for k in range(9, 9 + 5) if time.sleep(0.1) is None]
    wait_for(lambda: cli.received.n_tracks(sensor) >= 8 + 5, 20, "the good frames after it")
    time.sleep(0.3)
    errors = [e for e in pub.errors(timeout=0) if e.seq in good]
    assert errors == []
    with cli.received.lock:
        tracked = [f.seq for f, _ in cli.received.tracks[sensor][8:]]
    assert tracked[-5:] == good
    if seq != "same":
        assert last_ids(cli.received, sensor) == ids
    pub.close()
