"""Item 4: under overload with drop_oldest, every frame the service sheds is announced: the
seqs named by the drop notices, the dropped metric and the log agree with what was sent."""

from __future__ import annotations

from pathlib import Path

import pytest

from simpletrack.wire import ErrorReason, FrameError, encode_detection_frame
from tests.service_helpers import (
    Client,
    client,
    metric,
    moving_cars,
    stamp,
    start_service,
    wait_for,
)

pytestmark = pytest.mark.zenoh

HEAVY, LIGHT = "veh/heavy", "veh/light"


def named(errors: list[FrameError]) -> list[int | None]:
    """The seqs the notices stand for: a drop notice names them all, any other error its own."""
    return [s for e in errors for s in (e.seqs if e.seqs is not None else [e.seq])]


def snapshot(cli: Client, sensor: str) -> tuple[list[int], list[FrameError]]:
    with cli.received.lock:
        tracked = [f.seq for f, _ in cli.received.tracks.get(sensor, [])]
        return tracked, list(cli.received.errors.get(sensor, []))


def test_every_shed_frame_is_named_by_a_notice_and_counted_once(tmp_path: Path) -> None:
    # One worker with a short queue; heavy frames stall it while a light sensor floods, so
    # thousands of frames are shed while it is busy (the old queue kept ~1000 notices).
    env = {"SIMPLETRACK_QUEUE_SIZE": "8", "SIMPLETRACK_WORKERS": "1"}
    svc = start_service(tmp_path, env=env, instance="svc-drops")
    sent = {HEAVY: 12, LIGHT: 6000}
    try:
        with client(svc.endpoint) as cli:
            heavy = [
                encode_detection_frame(
                    vehicle="veh", sensor="heavy", seq=k, stamp_ns=stamp(k), frame_id="lidar",
                    boxes=moving_cars(k, n=1500),
                )
                for k in range(sent[HEAVY])
            ]  # fmt: skip
            light = [
                encode_detection_frame(
                    vehicle="veh", sensor="light", seq=k, stamp_ns=stamp(k, 1_000_000),
                    frame_id="lidar", boxes=moving_cars(k, n=1),
                )
                for k in range(sent[LIGHT])
            ]  # fmt: skip
            per_heavy = sent[LIGHT] // sent[HEAVY]
            for k in range(sent[HEAVY]):
                cli.put("veh", "heavy", heavy[k])
                for p in light[k * per_heavy : (k + 1) * per_heavy]:
                    cli.put("veh", "light", p)

            def accounted() -> bool:
                return all(
                    len(t) + len(named(e)) == sent[s] for s in sent for t, e in [snapshot(cli, s)]
                )

            wait_for(accounted, 60, "every frame tracked or announced")
            m = svc.metrics()
            dropped = rejected = tracked_total = 0
            for sensor, n in sent.items():
                tracked, errors = snapshot(cli, sensor)
                drops = [e for e in errors if e.reason is ErrorReason.DROPPED_QUEUE_FULL]
                seqs = named(drops)
                # Each frame is either tracked or named once, never both, never lost.
                assert sorted(tracked + seqs) == list(range(n)), sensor  # type: ignore[operator]
                assert tracked == sorted(tracked) and tracked[-1] == n - 1, sensor
                dropped += len(seqs)
                rejected += len(named(errors)) - len(seqs)
                tracked_total += len(tracked)
            assert dropped > 1500, f"only {dropped} frames shed: the overload was too light"
            assert rejected == 0
            assert metric(m, "simpletrack_frames_received_total") == sum(sent.values())
            assert metric(m, "simpletrack_frames_tracked_total") == tracked_total
            assert metric(m, "simpletrack_frames_dropped_total", reason="dropped_queue_full") == (
                dropped
            )
            assert dropped == sum(sent.values()) - tracked_total - rejected
            assert metric(m, "simpletrack_queue_depth") == 0
    finally:
        assert svc.stop() == 0
    logged = [e for e in svc.logs() if e.get("event") == "frame_dropped"]
    assert sum(e.get("frames", 1) for e in logged) == dropped  # the log names them all too
