"""A sensor clock off the service's is a figure of its own, not a latency: a frame stamped
ahead of the service's clock is counted apart (never in the end-to-end latency, not even as
0), each sensor's clock is estimated (the least receipt - stamp of its recent frames), the
``stamp_offset`` warning fires from ``CLOCK_TOLERANCE_S`` (1 s), and /metrics carries no
``_created`` series."""

from __future__ import annotations

import time
import urllib.request
from pathlib import Path

import pytest
from prometheus_client import generate_latest

from simpletrack.server.metrics import HttpEndpoint, Metrics
from simpletrack.server.plausibility import CLOCK_WINDOW_NS, Cause, LeastLag, check_frame
from simpletrack.server.sensors import CLOCK_TOLERANCE_S, OrderRules
from simpletrack.wire import ServiceStatus, decode_message
from simpletrack.wire.codec import Rejection
from simpletrack.wire.reasons import ErrorReason
from tests.service_helpers import client, metric, moving_cars, start_service, wait_for

S = 10**9
NOW = 1_760_000_000 * S  # the service's clock at receipt
E2E = "simpletrack_end_to_end_seconds"
AHEAD = "simpletrack_clock_ahead_frames_total"
OFFSET_MAX = "simpletrack_clock_offset_max_seconds"
OFF_SENSORS = "simpletrack_clock_off_sensors"
OFFSET_BY_SENSOR = "simpletrack_clock_offset_seconds"


def samples(m: Metrics) -> dict[str, float]:
    """Every sample of the registry as ``name{labels}`` -> value (labels in export order)."""
    out = {}
    for line in generate_latest(m.registry).decode().splitlines():
        if line and not line.startswith("#"):
            name, _, value = line.rpartition(" ")
            out[name] = float(value)
    return out


def stamp_offset(stamp_ns: int, least_lag_ns: int | None = None) -> list[float]:
    """The ``stamp_offset`` findings' values of an ordinary frame received at NOW."""
    found = check_frame(moving_cars(0), stamp_ns, NOW, least_lag_ns=least_lag_ns)
    return [f.value for f in found if f.cause is Cause.STAMP_OFFSET]


# ------------------------------------------------------------------ end-to-end latency
def test_a_frame_stamped_3_s_ahead_is_no_latency_but_a_clock_ahead() -> None:
    m = Metrics()
    m.observe_end_to_end(NOW + 3 * S, NOW, NOW + 2_000_000, "v1")
    got = samples(m)
    assert got[f"{E2E}_count"] == 0
    assert got[f'{E2E}_bucket{{le="0.0001"}}'] == 0  # the fastest bucket, where a clamp put it
    assert got[AHEAD] == 1
    # A frame stamped 30 ms before its receipt is a latency, and only that.
    m.observe_end_to_end(NOW - 30_000_000, NOW, NOW + 2_000_000, "v1")
    got = samples(m)
    assert got[f"{E2E}_count"] == 1 and got[f'{E2E}_bucket{{le="0.025"}}'] == 0
    assert got[f'{E2E}_bucket{{le="0.05"}}'] == 1
    assert got[f"{E2E}_sum"] == pytest.approx(0.032)
    assert got[AHEAD] == 1


def test_frames_ahead_are_counted_by_vehicle_when_the_label_is_on() -> None:
    m = Metrics(vehicle_label=True)
    for _ in range(3):
        m.observe_end_to_end(NOW + 3 * S, NOW, NOW, "v1")
    m.observe_end_to_end(NOW + S // 2, NOW, NOW, "v2")
    got = samples(m)
    assert got[f'{AHEAD}{{vehicle="v1"}}'] == 3 and got[f'{AHEAD}{{vehicle="v2"}}'] == 1
    assert got[f"{E2E}_count"] == 0


# ------------------------------------------------------------------ the warning
@pytest.mark.parametrize(
    ("offset_s", "warns"),
    [(1.5, True), (-1.5, True), (0.5, False), (-0.5, False), (3.0, True), (-3.0, True)],
)
def test_the_stamp_offset_warning_fires_from_a_second(offset_s: float, warns: bool) -> None:
    # offset_s > 0: the sensor's clock behind the service's (every frame of it as late).
    stamp_ns = NOW - int(offset_s * S)
    lag = LeastLag().see(stamp_ns, NOW)
    assert stamp_offset(stamp_ns, lag) == ([pytest.approx(offset_s)] if warns else [])


def test_the_threshold_is_the_one_clock_tolerance() -> None:
    assert CLOCK_TOLERANCE_S == 1.0
    assert OrderRules(reset_gap_s=5.0, reset_backward_s=5.0).clock_tolerance_s == CLOCK_TOLERANCE_S
    within, beyond = int(CLOCK_TOLERANCE_S * S) - 1_000_000, int(CLOCK_TOLERANCE_S * S) + 1_000_000
    assert stamp_offset(NOW + within) == [] and stamp_offset(NOW - within) == []
    assert len(stamp_offset(NOW + beyond)) == 1 and len(stamp_offset(NOW - beyond)) == 1


def test_a_late_frame_is_no_clock_but_a_clock_behind_is() -> None:
    timely, clock = LeastLag(), LeastLag()
    t = NOW - 5 * S
    for k in range(50):  # 10 Hz, 20 ms delivery; the other sensor's clock 3 s behind
        timely.see(t + k * S // 10 - 20_000_000, t + k * S // 10)
        clock.see(t + k * S // 10 - 3 * S, t + k * S // 10)
    late = NOW - 4 * S  # a frame recovered 4 s after its capture
    assert stamp_offset(late, timely.see(late, NOW)) == []
    assert stamp_offset(NOW - 3 * S, clock.see(NOW - 3 * S, NOW)) == [pytest.approx(3.0)]
    # A frame stamped ahead needs no history: nothing arrives before it is captured.
    assert stamp_offset(NOW + 3 * S, timely.see(NOW + 3 * S, NOW)) == [pytest.approx(-3.0)]


def test_the_hint_says_how_far_and_which_way() -> None:
    found = check_frame(moving_cars(0), NOW + 3 * S, NOW, least_lag_ns=-3 * S)
    (f,) = [f for f in found if f.cause is Cause.STAMP_OFFSET]
    assert "clock is 3.0 s ahead of the service's" in f.hint, f.hint


# ------------------------------------------------------------------ the estimate
def test_least_lag_is_the_least_delay_of_the_last_windows() -> None:
    c = LeastLag()
    assert not c.fresh(NOW)
    assert c.see(NOW - 50_000_000, NOW) == 50_000_000
    assert c.see(NOW + S // 10 - 20_000_000, NOW + S // 10) == 20_000_000
    assert c.see(NOW + S // 5 - 900_000_000, NOW + S // 5) == 20_000_000  # a late frame
    # The clock is stepped back by 2 s (stamps 2 s behind from now on): the least holds for
    # up to two windows, then is relearned.
    t, leasts = NOW + S, []
    while t < NOW + S + 2 * CLOCK_WINDOW_NS + S:
        leasts.append(c.see(t - 2 * S - 20_000_000, t))
        t += S // 10
    assert leasts[50] == 20_000_000  # 5 s on: the window still holds the timely frames
    assert leasts[-1] == 2 * S + 20_000_000
    assert c.fresh(t) and not c.fresh(t + 2 * CLOCK_WINDOW_NS + S)


def test_least_lag_follows_a_clock_set_ahead_at_once() -> None:
    c = LeastLag()
    c.see(NOW - 20_000_000, NOW)
    assert c.see(NOW + 4 * S, NOW + S // 10) == -4 * S + S // 10


def test_the_clock_metrics_show_the_furthest_clock_each_way() -> None:
    m = Metrics()
    m.watch_clocks(lambda: [("v/a", -3 * S), ("v/b", 20_000_000), ("v/c", S // 2)])
    m.watch_clocks(lambda: [("w/a", -S // 2), ("w/late", 1_500_000_000)])
    got = samples(m)
    assert got[f'{OFFSET_MAX}{{side="ahead"}}'] == pytest.approx(3.0)
    assert got[f'{OFFSET_MAX}{{side="behind"}}'] == pytest.approx(1.5)
    assert got[f'{OFF_SENSORS}{{side="ahead"}}'] == 1
    assert got[f'{OFF_SENSORS}{{side="behind"}}'] == 1
    # The sensors off by more than a second, by name: > 0 ahead, < 0 behind.
    named = {k: v for k, v in got.items() if k.startswith(OFFSET_BY_SENSOR + "{")}
    assert named == {
        f'{OFFSET_BY_SENSOR}{{sensor="v/a"}}': pytest.approx(3.0),
        f'{OFFSET_BY_SENSOR}{{sensor="w/late"}}': pytest.approx(-1.5),
    }
    quiet = samples(Metrics())  # no sensor: every series there, at 0
    for side in ("ahead", "behind"):
        assert quiet[f'{OFFSET_MAX}{{side="{side}"}}'] == 0
        assert quiet[f'{OFF_SENSORS}{{side="{side}"}}'] == 0


# ------------------------------------------------------------------ no _created series
def test_metrics_text_has_no_created_series() -> None:
    m = Metrics(vehicle_label=True)
    m.count_received("v1")
    m.count_error(ErrorReason.OUT_OF_ORDER, "v1")
    m.observe_end_to_end(NOW - 30_000_000, NOW, NOW, "v1")
    m.stages["track"].observe(0.001)
    http = HttpEndpoint(m, "127.0.0.1", 0, lambda: True)
    http.start()
    try:
        with urllib.request.urlopen(f"http://127.0.0.1:{http.port}/metrics", timeout=5) as r:
            text = r.read().decode()
    finally:
        http.close()
    assert "simpletrack_frames_received_total" in text and f"{E2E}_count" in text
    created = [line for line in text.splitlines() if "_created" in line]
    assert created == [], created[:5]


# ------------------------------------------------------------------ the service
FRAMES = 8
# sensor -> its clock against the service's (s; > 0: ahead)
CLOCKS = {"ahead3": 3.0, "ahead05": 0.5, "late15": -1.5, "clean": 0.0}


@pytest.mark.zenoh
def test_the_service_keeps_clock_offsets_out_of_the_latency(tmp_path: Path) -> None:
    svc = start_service(tmp_path)
    try:
        before = svc.metrics()
        with client(svc.endpoint) as cli:
            for k in range(FRAMES):
                for sensor, ahead_s in CLOCKS.items():
                    at = time.time_ns() + int(ahead_s * S)
                    cli.send("v1", sensor, seq=k, stamp_ns=at, boxes=moving_cars(k))
                time.sleep(0.02)
            wait_for(
                lambda: all(cli.received.n_tracks(f"v1/{s}") == FRAMES for s in CLOCKS),
                20,
                "every frame of every sensor tracked",
            )
            [raw] = cli.get(f"fleet/@simpletrack/{svc.instance}/status")
            status = decode_message(raw, ServiceStatus)
            assert not isinstance(status, Rejection), status
        after = svc.metrics()
    finally:
        assert svc.stop() == 0

    def delta(name: str, **labels: str) -> float:
        return metric(after, name, **labels) - metric(before, name, **labels)

    # Latencies of the sensors whose stamps were behind their receipt only (clean, late15);
    # none of the sensors ahead in the fastest bucket, where a clamp to 0 put them.
    assert delta(f"{E2E}_count") == 2 * FRAMES
    assert delta(f"{E2E}_bucket", le="0.0001") == 0
    assert delta(AHEAD) == 2 * FRAMES  # ahead3 and ahead05
    assert delta("simpletrack_implausible_frames_total", cause="stamp_offset") == 2 * FRAMES
    assert 2.9 < metric(after, OFFSET_MAX, side="ahead") <= 3.0
    assert 1.5 <= metric(after, OFFSET_MAX, side="behind") < 1.6
    assert metric(after, OFF_SENSORS, side="ahead") == 1  # 0.5 s is within the tolerance
    assert metric(after, OFF_SENSORS, side="behind") == 1
    # Per sensor: the two off by more than a second are named in the metrics, ...
    assert 2.9 < metric(after, OFFSET_BY_SENSOR, sensor="v1/ahead3") <= 3.0
    assert -1.6 < metric(after, OFFSET_BY_SENSOR, sensor="v1/late15") <= -1.5
    assert not any("ahead05" in k or "clean" in k for k in after if OFFSET_BY_SENSOR in k)
    # ... the warning names it with its offset; the status counts its frames.
    warned = {
        e["sensor"]: e
        for e in svc.logs()
        if e["event"] == "implausible_frame" and e["cause"] == "stamp_offset"
    }
    assert sorted(warned) == ["ahead3", "late15"]
    assert (
        -3.0 <= warned["ahead3"]["value"] < -2.9 and "3.0 s ahead of" in warned["ahead3"]["likely"]
    )
    assert 1.5 <= warned["late15"]["value"] < 1.6 and "behind" in warned["late15"]["likely"]
    per_sensor = {x.sensor: x.implausible_frames for x in status.sensors}
    assert per_sensor == {"ahead3": FRAMES, "ahead05": 0, "late15": FRAMES, "clean": 0}


def test_only_the_ten_furthest_clocks_are_named() -> None:
    m = Metrics()
    m.watch_clocks(lambda: [(f"v/s{k:02d}", -(2 + k) * S) for k in range(30)])
    got = samples(m)
    named = sorted(k for k in got if k.startswith(OFFSET_BY_SENSOR + "{"))
    assert named == [f'{OFFSET_BY_SENSOR}{{sensor="v/s{k:02d}"}}' for k in range(20, 30)]
    assert got[f'{OFF_SENSORS}{{side="ahead"}}'] == 30
