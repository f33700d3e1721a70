"""A Rust vehicle streams at 10 Hz through a router that is killed (SIGKILL) for 3 s and
started again: its advanced publisher holds the frames of the outage in its cache and the
service recovers them, so the service tracks every frame, in order, and announces none
missed. With a cache shorter than the outage, every frame is tracked or counted missed, and
the `missed` notice reaches the vehicle on its errors key. (Tracks are not cached: those the
service sent in the instant the router died never reach the vehicle, which is why the
vehicle's own count may be one or two short.)"""

from __future__ import annotations

import json
import subprocess
import time
from pathlib import Path
from typing import Any

import pytest

from tests.faults.router_process import new_router, start_client_service
from tests.native.cargo_build import BUILD_TIMEOUT_S, example
from tests.service_helpers import metric, wait_for

pytestmark = [pytest.mark.native, pytest.mark.zenoh]

FRAMES = 60
PERIOD_S = 0.1
OUTAGE_S = 3.0
KILL_AFTER = 9  # the seq sent when the router goes: 1 s of frames


def _stream_through_an_outage(
    tmp_path: Path, vehicle: str, cache_frames: int
) -> tuple[dict[str, Any], list[int], dict[str, float]]:
    """(the publisher's summary, seqs of the tracks it got back, the service's metrics)."""
    publish = example("publish")
    router = new_router().start()
    svc = start_client_service(tmp_path, router.endpoint, "--preset", "kitti", instance="rust-out")
    proc: subprocess.Popen[str] | None = None
    try:
        wait_for(lambda: svc.http("/readyz")[0] == 200, 30, "the service ready through the router")
        # fmt: off
        cmd = [str(publish), "--endpoint", router.endpoint, "--mode", "client",
               "--vehicle", vehicle, "--frames", str(FRAMES), "--stream",
               "--period-ms", str(int(PERIOD_S * 1000)), "--timeout-s", "8",
               "--cache-frames", str(cache_frames)]
        # fmt: on
        proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        assert proc.stderr is not None
        early = []
        for line in proc.stderr:
            early.append(line)
            if line.strip() == f"sent {KILL_AFTER}":
                break
        assert early and early[-1].strip() == f"sent {KILL_AFTER}", "".join(early)
        router.kill()
        time.sleep(OUTAGE_S)
        router.start()  # blocks while it starts: the frames of that time are delayed, not lost
        stdout, stderr = proc.communicate(timeout=120)
        values = svc.metrics()
    finally:
        if proc is not None and proc.poll() is None:
            proc.kill()
            proc.wait()
        svc.stop()
        router.stop()
    summary: dict[str, Any] = json.loads(
        next(line for line in stderr.splitlines() if line.startswith("summary "))[8:]
    )
    assert proc.returncode in (0, 1), stderr[-2000:]  # 1: some tracks did not come back
    assert summary["sent"] == FRAMES, summary
    assert summary["held"] >= OUTAGE_S / PERIOD_S * 0.8, f"the outage held no frames: {summary}"
    rejected = {
        k: v for k, v in values.items() if k.startswith("simpletrack_frames_rejected_total")
    }
    assert not any(rejected.values()), rejected  # a late recovered frame: out_of_order
    tracked = [json.loads(line)["seq"] for line in stdout.splitlines() if '"tracks"' in line]
    assert tracked == sorted(set(tracked)), f"tracks came back out of order: {tracked}"
    return summary, tracked, values


# Each may be the first to build the crate.
@pytest.mark.timeout(BUILD_TIMEOUT_S + 100)
def test_frames_a_rust_vehicle_sent_during_a_router_outage_are_all_tracked(
    tmp_path: Path,
) -> None:
    summary, tracked, values = _stream_through_an_outage(tmp_path, "veh-rust-rec", 100)
    assert summary["lost"] == 0, summary
    assert metric(values, "simpletrack_frames_tracked_total") == FRAMES, values
    assert metric(values, "simpletrack_frames_dropped_total", reason="missed") == 0
    assert len(tracked) >= FRAMES - 2, sorted(set(range(FRAMES)) - set(tracked))


@pytest.mark.timeout(BUILD_TIMEOUT_S + 100)
def test_an_outage_longer_than_the_cache_is_announced_to_the_rust_vehicle(
    tmp_path: Path,
) -> None:
    summary, _, values = _stream_through_an_outage(tmp_path, "veh-rust-miss", 5)
    missed = metric(values, "simpletrack_frames_dropped_total", reason="missed")
    assert missed > 0 and summary["lost"] > 0, (missed, summary)
    assert metric(values, "simpletrack_frames_tracked_total") + missed == FRAMES, values
    assert summary["error_notices"].get("missed", 0) >= 1, summary
