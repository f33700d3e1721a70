"""``simpletrack serve`` end to end: frames that look like a unit mistake are counted by cause
in /metrics and logged once per sensor and cause at warning level with the likely cause, and
they are tracked and published as before; a clean neighbour gets no warning."""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from simpletrack.wire import BoxArrays, Rejection, ServiceStatus, decode_message
from tests.service_helpers import client, metric, moving_cars, start_service, wait_for

pytestmark = pytest.mark.zenoh
FRAMES = 6
PERIOD_NS = 100_000_000
IMPLAUSIBLE = "simpletrack_implausible_frames_total"


def turning(k: int) -> BoxArrays:
    """moving_cars with headings of 30°, 60° and 90° (radians, as the wire wants)."""
    b = moving_cars(k)
    return replace(b, yaw=np.radians([30.0, 60.0, 90.0]).astype(np.float32))


def degrees(k: int) -> BoxArrays:
    b = turning(k)
    return replace(b, yaw=np.degrees(b.yaw))


def millimetres(k: int) -> BoxArrays:
    b = moving_cars(k)  # sizes in mm are refused (over 100 m): a centre-only conversion bug
    return replace(b, center=b.center * np.float32(1000.0))


def decimetres(k: int) -> BoxArrays:
    b = moving_cars(k)
    return replace(b, size=b.size * np.float32(10.0))


def logits(k: int) -> BoxArrays:
    return replace(moving_cars(k), score=np.full(3, -3.0))


# sensor -> (boxes of frame k, stamp of frame k from the test's t0 in ns, cause, words)
SENSORS: dict[str, tuple[Callable[[int], BoxArrays], Callable[[int, int], int], str, str]] = {
    "deg": (degrees, lambda t0, k: t0 + k * PERIOD_NS, "yaw_degrees", "yaw looks like degrees"),
    "mm": (
        millimetres,
        lambda t0, k: t0 + k * PERIOD_NS,
        "center_unit",
        "centres look like millimetres",
    ),
    "dm": (decimetres, lambda t0, k: t0 + k * PERIOD_NS, "size_unit", "median longest side 40.0"),
    "logit": (logits, lambda t0, k: t0 + k * PERIOD_NS, "score_range", "look like logits (min -3)"),
    "sec": (turning, lambda t0, k: t0 // 10**9 + k, "stamp_seconds", "stamp looks like seconds"),
}


def test_implausible_frames_are_counted_logged_once_and_still_tracked(tmp_path: Path) -> None:
    svc = start_service(tmp_path, "--workers", "2")
    try:
        with client(svc.endpoint) as cli:
            t0 = time.time_ns()
            for k in range(FRAMES):
                for sensor, (boxes, stamp, _, _) in SENSORS.items():
                    cli.send("v1", sensor, seq=k, stamp_ns=stamp(t0, k), boxes=boxes(k))
                cli.send("v1", "clean", seq=k, stamp_ns=t0 + k * PERIOD_NS, boxes=turning(k))
                time.sleep(0.02)
            names = [*SENSORS, "clean"]
            wait_for(
                lambda: all(cli.received.n_tracks(f"v1/{s}") == FRAMES for s in names),
                20,
                "every frame of every sensor tracked",
            )
            assert all(cli.received.n_errors(f"v1/{s}") == 0 for s in names)
            # Tracked as before: the clean sensor's cars come out; degrees or not, so do theirs.
            assert len(cli.received.tracks["v1/clean"][-1][1]) == 3
            assert len(cli.received.tracks["v1/deg"][-1][1]) == 3
            assert len(cli.received.tracks["v1/logit"][-1][1]) == 0  # the silence now explained
            # Per sensor, in the status queryable: what the metric (by cause) cannot say.
            [raw] = cli.get(f"fleet/@simpletrack/{svc.instance}/status")
            status = decode_message(raw, ServiceStatus)
            assert not isinstance(status, Rejection), status
            per_sensor = {x.sensor: x.implausible_frames for x in status.sensors}
            assert per_sensor == {**{s: FRAMES for s in SENSORS}, "clean": 0}, per_sensor
        values = svc.metrics()
        for _, _, cause, _ in SENSORS.values():
            assert metric(values, IMPLAUSIBLE, cause=cause) == FRAMES, cause
        assert metric(values, IMPLAUSIBLE, cause="stamp_offset") == 0
    finally:
        assert svc.stop() == 0

    warnings = [e for e in svc.logs() if e["event"] == "implausible_frame"]
    assert all(e["level"] == "warning" and e["vehicle"] == "v1" for e in warnings)
    got = sorted((e["sensor"], e["cause"]) for e in warnings)
    assert got == sorted((s, cause) for s, (_, _, cause, _) in SENSORS.items())
    for e in warnings:
        words = SENSORS[e["sensor"]][3]
        assert words in e["likely"], e
