"""A key chunk ending in a newline (which a '$' pattern matched by ``re.match`` lets through)
is refused and counted, never a traceback; the same name in a payload is refused on the
errors key; the service carries on."""

from __future__ import annotations

from pathlib import Path

import pytest

from simpletrack.client.publisher import check_name
from simpletrack.wire import encode_detection_frame
from simpletrack.wire.reasons import ErrorReason
from tests.service_helpers import (
    client,
    metric,
    moving_cars,
    stamp,
    start_service,
    wait_for,
)

REJECTED = "simpletrack_frames_rejected_total"


def test_a_newline_in_a_key_chunk_is_counted_and_logged_and_the_sensor_carries_on(
    tmp_path: Path,
) -> None:
    svc = start_service(tmp_path, instance="svc-newline")
    try:
        with client(svc.endpoint) as cli:
            cli.send("car-30", "lidar", seq=0, stamp_ns=stamp(0), boxes=moving_cars(0))
            wait_for(lambda: cli.received.n_tracks("car-30/lidar") == 1, 20, "a good frame")
            before = svc.metrics()
            frame = encode_detection_frame(
                vehicle="car-30",
                sensor="lidar",
                seq=1,
                stamp_ns=stamp(1),
                frame_id="lidar",
                boxes=moving_cars(1),
            )
            for key in ("fleet/car-30\n/lidar/detections", "fleet/car-30/lidar\n/detections"):
                cli.session.put(key, frame)
            # The payload's own names end in a newline: refused on the key's errors key.
            bad = frame.replace(b"\xa5lidar", b"\xa6lidar\n", 1)  # msgpack fixstr
            cli.put("car-30", "lidar", bad)
            cli.send("car-30", "lidar", seq=1, stamp_ns=stamp(1), boxes=moving_cars(1))
            wait_for(lambda: cli.received.n_tracks("car-30/lidar") == 2, 20, "the next good one")
            wait_for(lambda: cli.received.n_errors("car-30/lidar") == 1, 20, "the payload's error")
            [err] = cli.received.errors["car-30/lidar"]
            assert (err.reason, err.field) == (ErrorReason.INVALID_VALUE, "sensor")
            after = svc.metrics()
            label = {"reason": "invalid_value"}
            assert metric(after, REJECTED, **label) - metric(before, REJECTED, **label) == 3
        logs = svc.logs()
        assert not [x for x in logs if x.get("event") == "worker_error"], "a traceback"
        refused = [x for x in logs if x.get("event") == "frame_rejected" and x.get("key")]
        assert {x["key"] for x in refused} == {
            "fleet/car-30\n/lidar/detections",
            "fleet/car-30/lidar\n/detections",
        }
    finally:
        svc.stop()


@pytest.mark.parametrize("name", ["car-30\n", "\ncar-30", "car\n30"])
def test_the_client_refuses_a_name_with_a_newline(name: str) -> None:
    with pytest.raises(ValueError, match="must be 1-64"):
        check_name("vehicle", name)
