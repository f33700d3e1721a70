"""Item 5: a sensor flooding garbage, or a flood of wildcard snapshot queries, on the worker
of a well-behaved sensor leaves that sensor's frames all tracked and its latency near the
baseline measured in the same test, with the same service."""

from __future__ import annotations

import signal
import subprocess
import sys
import textwrap
import threading
import time
from pathlib import Path

import numpy as np
import pytest
import zenoh

from simpletrack.wire import Rejection, decode_track_frame
from tests.service_helpers import ROOT, Client, client, moving_cars, stamp, start_service, wait_for

pytestmark = pytest.mark.zenoh

FRAMES = 40  # per phase, at 20 Hz
PERIOD_S = 0.05

# A separate process, as a real noisy sensor or a misbehaving tool would be: the test's own
# interpreter stays free to measure.
FLOODER = textwrap.dedent(
    """
    import sys, zenoh
    from simpletrack.session import open_session
    endpoint, what = sys.argv[1], sys.argv[2]
    session = open_session(mode="peer", connect=[endpoint])
    if what == "garbage":
        pub = session.declare_publisher("fleet/veh/noisy/detections")
        junk = [bytes([0xC1]) * n for n in range(1, 64)]
        print("flooding", flush=True)
        while True:
            for j in junk:
                pub.put(j)
    else:
        print("flooding", flush=True)
        while True:
            session.get("fleet/@simpletrack/svc-fair/snapshot/**", lambda reply: None)
    """
)


def flood(endpoint: str, what: str) -> subprocess.Popen[bytes]:
    proc = subprocess.Popen(
        [sys.executable, "-c", FLOODER, endpoint, what], cwd=ROOT, stdout=subprocess.PIPE
    )
    assert proc.stdout is not None and proc.stdout.readline() == b"flooding\n"
    time.sleep(0.5)  # let the flood reach its pace before measuring
    return proc


def latencies(cli: Client, first: int) -> list[float]:
    """Send FRAMES frames of the calm sensor from seq ``first`` at 20 Hz; the time from each
    put to its tracks. Every frame must be tracked."""
    arrived: dict[int, float] = {}
    done = threading.Condition()

    def on_tracks(sample: zenoh.Sample) -> None:
        t = time.perf_counter()
        out = decode_track_frame(sample.payload.to_bytes())
        assert not isinstance(out, Rejection), out
        with done:
            arrived[out[0].seq - first] = t
            done.notify_all()

    sub = cli.session.declare_subscriber("fleet/veh/calm/tracks", on_tracks)
    try:
        before = cli.received.n_tracks("veh/calm")
        sent = []
        for k in range(first, first + FRAMES):
            sent.append(time.perf_counter())
            cli.send("veh", "calm", seq=k, stamp_ns=stamp(k), boxes=moving_cars(k, n=8))
            time.sleep(max(0.0, sent[-1] + PERIOD_S - time.perf_counter()))
        with done:
            done.wait_for(lambda: len(arrived) == FRAMES, timeout=20)
        assert cli.received.n_tracks("veh/calm") - before == len(arrived) == FRAMES
        assert sorted(arrived) == list(range(FRAMES))
        assert cli.received.n_errors("veh/calm") == 0
        return [arrived[i] - sent[i] for i in range(FRAMES)]
    finally:
        sub.undeclare()  # type: ignore[no-untyped-call]


def within(baseline: list[float], now: list[float], what: str) -> None:
    b50, b99 = np.percentile(baseline, [50, 99])
    p50, p99 = np.percentile(now, [50, 99])
    report = f"{what}: p50 {p50 * 1e3:.1f} ms, p99 {p99 * 1e3:.1f} ms (baseline {b50 * 1e3:.1f}/{b99 * 1e3:.1f})"
    print(report)
    # A flood that overloads the worker also takes most of the interpreter lock and a core:
    # the bound leaves room for that on a shared 2-core machine. The fault it guards against
    # cost seconds (the calm sensor's frames waited behind, or were shed for, the flood's);
    # p99 of 40 frames is nearly their maximum, so one scheduling hiccup shows in it.
    assert p50 <= 2 * b50 + 0.020, report
    assert p99 <= 2 * b99 + 0.200, report


def test_a_garbage_flood_and_a_query_flood_leave_the_calm_sensor_untouched(
    tmp_path: Path,
) -> None:
    env = {"SIMPLETRACK_WORKERS": "1", "SIMPLETRACK_QUEUE_SIZE": "64"}
    svc = start_service(tmp_path, env=env, instance="svc-fair")
    try:
        with client(svc.endpoint) as cli:
            cli.send("veh", "calm", seq=0, stamp_ns=stamp(0), boxes=moving_cars(0, n=8))
            wait_for(lambda: cli.received.n_tracks("veh/calm") == 1, 10, "the calm sensor")
            baseline = latencies(cli, 1)
            seq = 1 + FRAMES
            for what in ("garbage", "queries"):
                flooder = flood(svc.endpoint, what)
                try:
                    within(baseline, latencies(cli, seq), what)
                finally:
                    flooder.send_signal(signal.SIGKILL)
                    flooder.wait()
                seq += FRAMES
            m = svc.metrics()
            rejected = m.get('simpletrack_frames_rejected_total{reason="malformed"}', 0)
            assert rejected > FRAMES
    finally:
        assert svc.stop() == 0
    # Thousands refused, each announced on the errors key; the log has the first line and
    # then one per 10 s with the count not logged (the last at the stop, or none yet).
    lines = [
        e for e in svc.logs() if e.get("event") == "frame_rejected" and e.get("sensor") == "noisy"
    ]
    assert 1 <= len(lines) <= 4, len(lines)
    assert sum(1 + e.get("repeated", 0) for e in lines) <= rejected
