"""Item 8: a TrackSubscriber that receives an invalid frame says so: it logs a warning (at most
one line a second, counting those it held back), counts it by reason and calls ``on_invalid``;
valid frames around it still arrive."""

from __future__ import annotations

import logging
import threading
import time
from pathlib import Path

import msgpack
import numpy as np
import pytest
import zenoh

from simpletrack.client import TrackSubscriber
from simpletrack.client.subscriber import INVALID_LOG_INTERVAL_S
from simpletrack.session import open_session
from simpletrack.spawn import free_port
from simpletrack.wire import Rejection
from tests.service_helpers import wait_for

pytestmark = pytest.mark.zenoh
VECTORS = Path(__file__).resolve().parents[2] / "schemas" / "vectors"


def _with_inf(valid: bytes) -> bytes:
    """The golden track frame with one centre at +inf: what the service used to publish for a
    box at 3.4e38 m."""
    obj = msgpack.unpackb(valid, raw=False)
    centre = np.frombuffer(obj["tracks"]["center"], np.float32).copy()
    centre[0] = np.inf
    obj["tracks"]["center"] = centre.tobytes()
    return bytes(msgpack.packb(obj, use_bin_type=True))


def test_invalid_track_frames_are_logged_counted_and_reported(
    caplog: pytest.LogCaptureFixture,
) -> None:
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    valid = (VECTORS / "tracks_basic.msgpack").read_bytes()
    seen: list[tuple[str, Rejection]] = []
    lock = threading.Lock()

    def on_invalid(key: str, r: Rejection) -> None:
        with lock:
            seen.append((key, r))

    caplog.set_level(logging.WARNING, logger="simpletrack.client.subscriber")
    with (
        open_session(mode="peer", listen=[endpoint], connect=[]) as vehicle_side,
        open_session(mode="peer", listen=[], connect=[endpoint]) as planner_side,
    ):
        sub = TrackSubscriber(planner_side, vehicle="truck-07", on_invalid=on_invalid)
        key = "fleet/truck-07/lidar_top/tracks"
        pub = vehicle_side.declare_publisher(key, congestion_control=zenoh.CongestionControl.BLOCK)
        wait_for(lambda: pub.matching_status.matching, 10, "the subscriber")
        for payload in (valid, b"\xc1 not msgpack", _with_inf(valid), valid):
            pub.put(payload)
        # The valid frame sent twice is one frame (same sensor, seq, stamp): delivered once.
        wait_for(
            lambda: sub.received == 1 and sub.duplicates == 1 and sub.invalid == 2, 10, "4 samples"
        )
        # One line for the first; the second came within the second and is held back...
        lines = [r for r in caplog.records if r.name == "simpletrack.client.subscriber"]
        assert len(lines) == 1 and lines[0].levelno == logging.WARNING
        assert key in lines[0].getMessage() and "malformed" in lines[0].getMessage()
        time.sleep(INVALID_LOG_INTERVAL_S)
        pub.put(b"")
        wait_for(lambda: sub.invalid == 3, 10, "the fifth sample")
        sub.close()

    # ... and counted on the next line.
    lines = [r for r in caplog.records if r.name == "simpletrack.client.subscriber"]
    assert len(lines) == 2
    assert "3 invalid so far, 1 more since the last line" in lines[1].getMessage()
    assert (sub.invalid, sub.invalid_reasons) == (3, {"malformed": 2, "non_finite": 1})
    assert [(k, r.reason.value, r.field) for k, r in seen] == [
        (key, "malformed", "payload"),
        (key, "non_finite", "tracks.center"),
        (key, "malformed", "payload"),
    ]
    assert sub.last_rejection is seen[-1][1]
