"""A sustained burst in ``block`` mode: every frame is answered, none vanishes.

Zenoh closes a link once a BLOCK put has waited ``wait_before_close`` (5 s by default) and
drops what was queued on it without telling the publisher. 20,000 frames put as fast as
possible sit mostly in the loopback socket buffers; the service needs far longer than 5 s to
work through them, so with Zenoh's default only ~5,000 were ever received (session.py)."""

from __future__ import annotations

import tempfile
import threading
import time

import numpy as np
import pytest
import zenoh

from simpletrack.bench.fuzz import valid_frame
from simpletrack.session import ZenohOptions, open_session
from simpletrack.spawn import spawned_service
from simpletrack.wire.keys import Keys

pytestmark = pytest.mark.zenoh

FRAMES, SENSORS = 20_000, 20


def test_a_burst_far_past_what_the_workers_drain_in_seconds_is_answered_in_full() -> None:
    keys, rng = Keys(), np.random.default_rng(0)
    payloads = [
        (k % SENSORS, valid_frame(f"v{k % SENSORS}", "s", k // SENSORS, rng)) for k in range(FRAMES)
    ]
    answers = [0]
    lock = threading.Lock()

    def on_answer(_sample: zenoh.Sample) -> None:
        with lock:
            answers[0] += 1

    def answered() -> int:
        with lock:
            return answers[0]

    with (
        tempfile.TemporaryFile() as log,
        spawned_service("kitti", log=log) as svc,
        open_session(ZenohOptions(connect=[svc.endpoint])) as session,
        session.declare_subscriber(keys.tracks("*", "*"), on_answer),
        session.declare_subscriber(keys.errors("*", "*"), on_answer),
    ):
        pubs = [
            session.declare_publisher(
                keys.detections(f"v{i}", "s"), congestion_control=zenoh.CongestionControl.BLOCK
            )
            for i in range(SENSORS)
        ]
        time.sleep(0.5)  # the service's subscriber reaches this session
        longest_put = 0.0
        for i, payload in payloads:
            start = time.monotonic()
            pubs[i].put(payload)
            longest_put = max(longest_put, time.monotonic() - start)
        last, since = -1, time.monotonic()
        while answered() < FRAMES and time.monotonic() - since < 15:
            if answered() != last:
                last, since = answered(), time.monotonic()
            time.sleep(0.2)
    assert answered() == FRAMES, (
        f"{answered()} of {FRAMES} answered (longest put {longest_put:.1f} s)"
    )
