"""The vehicle's reorder buffer (core/reorder.py): frames go in stamp order whatever order
they arrived in within the window; a dead sensor costs the window, then nothing."""

from __future__ import annotations

import numpy as np

from simpletrack.core.reorder import ReorderBuffer

SENSORS = ("lidar", "camera")


def _frames(seconds: float) -> list[tuple[str, int, int]]:
    """(sensor, seq, stamp_ns): lidar 10 Hz, camera 15 Hz."""
    out = [("lidar", k, k * 100_000_000) for k in range(int(seconds * 10))]
    out += [("camera", k, k * 66_666_667) for k in range(int(seconds * 15))]
    return out


def _run(
    arrivals: list[tuple[float, tuple[str, int, int]]], window: float
) -> list[tuple[str, int, int]]:
    buf: ReorderBuffer[tuple[str, int, int]] = ReorderBuffer(SENSORS, window, 1.0)
    # Both sensors heard once before: a sensor never heard is not waited for (its first
    # frames may then be late, which the vehicle tracker re-processes).
    for sensor in SENSORS:
        buf.push(sensor, -1, -1, (sensor, -1, -1), now=-0.5)
    buf.pop_ready(-0.5)
    out: list[tuple[str, int, int]] = []
    for now, f in sorted(arrivals, key=lambda a: a[0]):
        buf.push(f[0], f[1], f[2], f, now)
        out += buf.pop_ready(now)
    return out + buf.flush()


def test_shuffled_arrivals_within_the_window_come_out_in_stamp_order() -> None:
    frames = _frames(3.0)
    want = sorted(frames, key=lambda f: (f[2], SENSORS.index(f[0]), f[1]))
    rng = np.random.default_rng(0)
    for _ in range(20):
        # Each frame arrives 10-150 ms after its stamp (a camera's detector), each sensor's
        # own frames in order.
        arrivals = []
        for sensor in SENSORS:
            now = 0.0
            for f in (f for f in frames if f[0] == sensor):
                now = max(now, f[2] * 1e-9 + rng.uniform(0.01, 0.15))
                arrivals.append((now, f))
        assert _run(arrivals, window=0.3) == want


def test_a_dead_sensor_delays_the_others_by_the_window_then_not_at_all() -> None:
    buf: ReorderBuffer[int] = ReorderBuffer(SENSORS, 0.3, 1.0)
    buf.push("camera", 0, 0, -1, now=0.0)
    assert buf.pop_ready(0.0) == [-1]  # the lidar was never heard: not waited for
    buf.push("lidar", 0, 10, 0, now=0.01)
    assert buf.pop_ready(0.01) == []  # the camera is live and has not passed stamp 10
    assert buf.due() == 0.01 + 0.3
    assert buf.pop_ready(0.30) == []
    assert buf.pop_ready(0.31) == [0]  # the window
    buf.push("lidar", 1, 20, 1, now=1.5)  # the camera silent for over silent_after_s
    assert buf.pop_ready(1.5) == [1]


def test_equal_stamps_go_in_the_configured_sensor_order() -> None:
    buf: ReorderBuffer[str] = ReorderBuffer(SENSORS, 0.3, 1.0)
    buf.push("camera", 7, 100, "camera", now=0.0)
    buf.push("lidar", 3, 100, "lidar", now=0.0)
    assert buf.flush() == ["lidar", "camera"]


def test_a_sensor_assumed_heard_is_waited_for_as_one_heard() -> None:
    """A state taken over starts a new buffer: the sensors it had live are assumed heard,
    so a camera frame does not go ahead of the lidar's stamped before it."""
    fresh: ReorderBuffer[int] = ReorderBuffer(SENSORS, 0.3, 1.0)
    fresh.push("camera", 29, 2_900, 29, now=10.0)
    assert fresh.pop_ready(10.0) == [29]  # nothing known of the lidar: not waited for

    taken: ReorderBuffer[int] = ReorderBuffer(SENSORS, 0.3, 1.0)
    taken.assume_heard("lidar", 2_500, now=10.0)
    taken.push("camera", 29, 2_900, 29, now=10.0)
    assert taken.pop_ready(10.0) == []  # the lidar is live and has not passed stamp 2,900
    taken.push("lidar", 28, 2_800, 28, now=10.1)
    assert taken.pop_ready(10.1) == [28]  # in stamp order; the camera waits on
    assert taken.pop_ready(10.3) == [29]  # its window
    assumed: ReorderBuffer[int] = ReorderBuffer(SENSORS, 0.3, 1.0)
    assumed.assume_heard("lidar", 2_500, now=10.0)
    assumed.push("camera", 29, 2_900, 29, now=11.5)
    assert assumed.pop_ready(11.5) == [29]  # silent for silent_after_s since: not waited for


def test_a_frame_is_ready_at_the_time_the_buffer_says_it_is_due() -> None:
    # A worker sleeps until due() and asks again. At 1500.0 s of the monotonic clock,
    # (1500.0 + 0.3) - 1500.0 rounds below 0.3: the frame was judged still in its window at
    # its own deadline (a test at that clock value failed; the worker would have slept again).
    for arrived in (1500.0, 1234.5678, 3.0, 98765.4321):
        buf: ReorderBuffer[str] = ReorderBuffer(SENSORS, 0.3, 10.0)
        buf.push("lidar", 1, 100, "lidar 1", arrived)
        buf.push("camera", 1, 200, "camera 1", arrived)  # waits for the lidar's next frame
        assert buf.pop_ready(arrived) == ["lidar 1"]
        deadline = buf.due()
        assert deadline is not None
        assert buf.pop_ready(deadline) == ["camera 1"], arrived
