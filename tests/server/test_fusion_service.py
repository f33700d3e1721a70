"""A fused vehicle through a real service (docs/SERVICE.md, "Vehicle fusion"): frames go to
the vehicle's tracker in stamp order whatever order they arrive in within the window; a
frame past the window is re-processed, one past the history refused as late; a sensor
whose clock or mounting is off is flagged and changes no track; a dead camera costs the
window, then nothing.

Each test compares the service's VehicleTrackFrames with the core's fused tracker run on
the same frames in stamp order (tests/fusion_scenario.py)."""

from __future__ import annotations

import contextlib
import json
import threading
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import zenoh

from simpletrack.wire import (
    FrameError,
    Rejection,
    ServiceStatus,
    decode_message,
    decode_vehicle_track_frame,
)
from simpletrack.wire.keys import Keys
from simpletrack.wire.messages import VehicleTrackFrame
from simpletrack.wire.reasons import ErrorReason, SensorCondition
from tests.fusion_scenario import (
    VEHICLE,
    WireFrame,
    expected,
    frames,
    fusion_of,
    same_tracks,
    write_config,
)
from tests.service_helpers import client, metric, start_service, wait_for

pytestmark = pytest.mark.zenoh


class Planner:
    """The vehicle's fused tracks and every sensor's refusals, as received."""

    def __init__(self, session: zenoh.Session) -> None:
        self.messages: list[tuple[VehicleTrackFrame, object]] = []
        self.errors: list[FrameError] = []
        self._lock = threading.Lock()
        keys = Keys()
        self._subs = [
            session.declare_subscriber(keys.vehicle_tracks(VEHICLE), self._on_tracks),
            session.declare_subscriber(f"fleet/{VEHICLE}/*/errors", self._on_error),
        ]

    def _on_tracks(self, sample: zenoh.Sample) -> None:
        out = decode_vehicle_track_frame(sample.payload.to_bytes())
        assert not isinstance(out, Rejection), out
        with self._lock:
            self.messages.append(out)

    def _on_error(self, sample: zenoh.Sample) -> None:
        err = decode_message(sample.payload.to_bytes(), FrameError)
        assert not isinstance(err, Rejection), err
        with self._lock:
            self.errors.append(err)

    def n(self) -> int:
        with self._lock:
            return len(self.messages)


def _send(c: object, frames_in_order: list[WireFrame], pause_s: float = 0.0) -> None:
    for f in frames_in_order:
        c.put(VEHICLE, f.sensor, f.payload())  # type: ignore[attr-defined]
        if pause_s:
            time.sleep(pause_s)


def _past(seconds: float = 30.0) -> int:
    """A start stamp in the past: no frame's stamp runs ahead of the service's clock."""
    return time.time_ns() - round(seconds * 1e9)


@contextlib.contextmanager
def _fusing(tmp_path: Path, window_s: float) -> Iterator[tuple[Any, Planner, int]]:
    """A service fusing the vehicle (``silent_after_s`` 1 s), a client and its planner, and
    a start stamp 0.2 s from now: frames sent in real time (``_in_real_time``)."""
    config = write_config(tmp_path, window_s=window_s, silent_after_s=1.0)
    svc = start_service(tmp_path, "--config", str(config))
    try:
        with client(svc.endpoint) as c:
            yield c, Planner(c.session), time.time_ns() + 200_000_000
    finally:
        svc.stop()


def _in_real_time(c: Any, wire: list[WireFrame]) -> None:
    """Each frame put at its stamp, or at once once that has passed."""
    for f in wire:
        time.sleep(max(0.0, (f.stamp_ns - time.time_ns()) * 1e-9))
        c.put(VEHICLE, f.sensor, f.payload())


def _check_against_core(messages: list, want: list) -> None:
    assert len(messages) == len(want), (len(messages), len(want))
    for k, ((frame, tracks), w) in enumerate(zip(messages, want, strict=True)):
        assert frame.seq == k
        same_tracks(tracks, w)


def test_arrivals_shuffled_within_the_window_give_the_in_order_tracks(tmp_path: Path) -> None:
    config = write_config(tmp_path)
    wire = frames(3.0, _past())
    want = expected(wire, fusion_of(config))
    svc = start_service(tmp_path, "--config", str(config))
    try:
        with client(svc.endpoint) as c:
            planner = Planner(c.session)
            # The first of each sensor in order (a sensor never heard is not waited for);
            # then each sensor's frames in its own order, the two streams interleaved at
            # random: the camera up to 200 ms behind the lidar or ahead of it.
            rng = np.random.default_rng(7)
            head, rest = wire[:2], wire[2:]
            arrival, last = [], 0.0
            for f in rest:  # the camera's own frames stay in order
                t = f.stamp_ns * 1e-9
                if f.sensor == "camera":
                    t = last = max(last, t + rng.uniform(0.0, 0.2))
                arrival.append(t)
            shuffled = [rest[i] for i in sorted(range(len(rest)), key=arrival.__getitem__)]
            assert [f.seq for f in shuffled if f.sensor == "camera"] == sorted(
                f.seq for f in rest if f.sensor == "camera"
            )
            assert [f.sensor for f in shuffled] != [f.sensor for f in rest]
            _send(c, head, 0.05)
            _send(c, shuffled, 0.005)
            wait_for(lambda: planner.n() >= len(want), 20, "every fused message")
            time.sleep(0.3)
            _check_against_core(planner.messages, want)
            assert planner.errors == []
            m = svc.metrics()
    finally:
        svc.stop()
    assert metric(m, "simpletrack_fusion_frames_total", outcome="applied") == len(wire)


def test_a_camera_frame_120_ms_late_is_applied_in_stamp_order(tmp_path: Path) -> None:
    config = write_config(tmp_path)
    wire = frames(2.0, _past())
    want = expected(wire, fusion_of(config))
    late = next(f for f in wire if f.sensor == "camera" and f.seq == 12)
    svc = start_service(tmp_path, "--config", str(config))
    try:
        with client(svc.endpoint) as c:
            planner = Planner(c.session)
            before = [f for f in wire if f.stamp_ns <= late.stamp_ns and f is not late]
            after = [f for f in wire if f.stamp_ns > late.stamp_ns]
            _send(c, before, 0.005)
            lidar_next = [f for f in after if f.sensor == "lidar"][:2]
            _send(c, lidar_next)  # later-stamped lidar frames first
            time.sleep(0.12)
            _send(c, [late])  # 120 ms after them
            _send(c, [f for f in after if all(f is not g for g in lidar_next)], 0.005)
            wait_for(lambda: planner.n() >= len(want), 20, "every fused message")
            time.sleep(0.3)
            _check_against_core(planner.messages, want)
            triggers = [(f.sensor, f.sensor_seq) for f, _ in planner.messages]
            assert triggers.index(("camera", 12)) < triggers.index(("lidar", lidar_next[0].seq))
            m = svc.metrics()
    finally:
        svc.stop()
    assert metric(m, "simpletrack_fusion_frames_total", outcome="reprocessed") == 0


def test_frames_past_the_window_are_reprocessed_and_past_the_history_refused(
    tmp_path: Path,
) -> None:
    config = write_config(tmp_path, window_s=0.1, history_s=1.0)
    wire = frames(4.0, _past())
    t0 = wire[0].stamp_ns

    def part(sensor: str, start_s: float, stop_s: float) -> list[WireFrame]:
        lo, hi = t0 + round(start_s * 1e9), t0 + round(stop_s * 1e9)
        return [f for f in wire if f.sensor == sensor and lo <= f.stamp_ns < hi]

    svc = start_service(tmp_path, "--config", str(config))
    try:
        with client(svc.endpoint) as c:
            planner = Planner(c.session)
            both = sorted(
                part("lidar", 0, 1.3) + part("camera", 0, 1.3),
                key=lambda f: (f.stamp_ns, f.sensor != "lidar"),
            )
            _send(c, both, 0.01)
            _send(c, part("lidar", 1.3, 1.9), 0.01)  # the camera's frames held back
            time.sleep(0.3)
            # 0.6 s behind the vehicle, within history_s: re-processed into place.
            _send(c, part("camera", 1.3, 1.9), 0.01)
            _send(c, part("lidar", 1.9, 3.9), 0.01)
            time.sleep(0.3)
            # Over 1.6 s behind: older than history_s, refused; three in a row flag it.
            too_old = part("camera", 1.9, 2.1)
            assert len(too_old) == 3
            _send(c, too_old, 0.01)
            wait_for(
                lambda: len([e for e in planner.errors if e.reason is ErrorReason.LATE]) >= 3,
                10,
                "three late refusals",
            )
            time.sleep(0.2)
            m = svc.metrics()
            status = _status(c)
    finally:
        svc.stop()
    late_errors = [e for e in planner.errors if e.reason is ErrorReason.LATE]
    assert sorted(e.seq for e in late_errors) == [f.seq for f in too_old]
    assert all(e.sensor == "camera" and "history_s" in e.detail for e in late_errors)
    assert metric(m, "simpletrack_fusion_frames_total", outcome="late") == 3
    reprocessed = metric(m, "simpletrack_fusion_frames_total", outcome="reprocessed")
    assert reprocessed >= 5  # the camera's frames that came after later lidar frames
    assert metric(m, "simpletrack_frames_rejected_total", reason="late") == 3
    vehicle = next(v for v in status.vehicles if v.vehicle == VEHICLE)
    assert vehicle.late_frames == 3
    assert vehicle.reprocessed_frames > reprocessed  # each brought frames after it again
    camera = next(s for s in vehicle.sensors if s.sensor == "camera")
    assert camera.state is SensorCondition.CLOCK and "behind" in camera.detail
    # Messages only ever move forward in time (re-processing publishes nothing of its own).
    stamps = [f.stamp_ns for f, _ in planner.messages]
    assert stamps == sorted(stamps)


def _status(c: object) -> ServiceStatus:
    for payload in c.get("fleet/@simpletrack/*/status"):  # type: ignore[attr-defined]
        status = decode_message(payload, ServiceStatus)
        assert not isinstance(status, Rejection)
        return status
    raise AssertionError("no status")


@pytest.mark.parametrize(
    ("fault", "condition"),
    [("clock", SensorCondition.CLOCK), ("extrinsic", SensorCondition.EXTRINSIC)],
)
def test_a_camera_with_its_clock_or_mounting_off_is_flagged_and_changes_no_track(
    tmp_path: Path, fault: str, condition: SensorCondition
) -> None:
    config = write_config(tmp_path, verify=True)
    svc = start_service(tmp_path, "--config", str(config))
    try:
        with client(svc.endpoint) as c:
            planner = Planner(c.session)
            # Stamped from now, once the service is up, and sent in real time: the lidar's
            # frames after the camera's first window carry the camera's condition. (Stamped
            # before the service started, every frame was due at once: in a burst, the
            # lidar's could all go before the camera's first left its window.)
            wire = frames(3.0, time.time_ns() + 200_000_000)
            if fault == "clock":  # the camera's clock 5 s ahead of every other clock
                wire = [f if f.sensor == "lidar" else _moved(f, stamp=5_000_000_000) for f in wire]
            else:  # mounted 20 m off from what its extrinsic says
                m = np.eye(4)
                m[0, 3] = 20.0
                wire = [
                    f if f.sensor == "lidar" else _moved(f, extrinsic=f.extrinsic @ m) for f in wire
                ]
            for f in wire:  # each at its lidar-clock time: the camera's stamps run 5 s ahead
                due = f.stamp_ns - (
                    5_000_000_000 if fault == "clock" and f.sensor == "camera" else 0
                )
                time.sleep(max(0.0, (due - time.time_ns()) * 1e-9))
                c.put(VEHICLE, f.sensor, f.payload())
            alone = expected(wire, fusion_of(config), skip="camera")
            wait_for(lambda: planner.n() >= len(alone), 20, "the lidar's fused messages")
            time.sleep(0.4)
            status = _status(c)
    finally:
        svc.stop()
    _check_against_core(planner.messages, alone)
    vehicle = next(v for v in status.vehicles if v.vehicle == VEHICLE)
    camera = next(s for s in vehicle.sensors if s.sensor == "camera")
    assert camera.state is condition, camera
    assert camera.detail
    assert planner.messages[-1][0].sensor_state[1] is condition
    if fault == "clock":
        flagged = [e for e in planner.errors if e.reason is ErrorReason.SENSOR_FLAGGED]
        assert len(flagged) == sum(1 for f in wire if f.sensor == "camera")
        assert "ahead" in flagged[0].detail
    else:
        assert "20." in camera.detail
    assert any(
        line.get("event") == "sensor_condition" and line.get("condition") == condition.value
        for line in svc.logs()
    ), json.dumps(svc.logs()[-5:])


def test_a_fused_frame_without_pose_or_on_another_key_is_refused_and_an_unfused_one_tracked(
    tmp_path: Path,
) -> None:
    config = write_config(tmp_path)
    first = frames(0.5, _past())[0]  # the lidar's
    svc = start_service(tmp_path, "--config", str(config))
    unfused: list[bytes] = []
    try:
        with client(svc.endpoint) as c:
            planner = Planner(c.session)
            c.session.declare_subscriber(
                f"fleet/{VEHICLE}/radar/tracks", lambda s: unfused.append(s.payload.to_bytes())
            )
            c.put(VEHICLE, "lidar", first.payload(extrinsic=None))
            c.put(VEHICLE, "camera", first.payload())  # the lidar's frame on the camera's key
            # A sensor the vehicle does not fuse needs neither (the KITTI and nuScenes data).
            c.put(VEHICLE, "radar", first.payload(sensor="radar", extrinsic=None))
            wait_for(
                lambda: len(planner.errors) >= 2 and unfused, 10, "the refusals, the radar's tracks"
            )
            time.sleep(0.3)
    finally:
        svc.stop()
    no_pose, mismatch = sorted(planner.errors, key=lambda e: e.sensor != "lidar")
    assert (no_pose.reason, no_pose.field, no_pose.seq) == (
        ErrorReason.MISSING_FIELD,
        "pose",
        first.seq,
    )
    assert "sensor->world pose" in no_pose.detail and "sensor->vehicle" in no_pose.detail
    assert (mismatch.sensor, mismatch.reason, mismatch.field) == (
        "camera",
        ErrorReason.KEY_MISMATCH,
        "sensor",
    )
    assert planner.n() == 0


def _moved(f: WireFrame, stamp: int = 0, extrinsic: np.ndarray | None = None) -> WireFrame:
    from dataclasses import replace

    return replace(
        f,
        stamp_ns=f.stamp_ns + stamp,
        extrinsic=f.extrinsic if extrinsic is None else extrinsic,
    )


def test_a_killed_camera_costs_the_window_then_nothing_and_is_reported_silent(
    tmp_path: Path,
) -> None:
    window = 0.3
    with _fusing(tmp_path, window) as (c, planner, start):
        death = start + 2_000_000_000  # the camera sends nothing from 2 s on
        wire = frames(5.0, start)
        _in_real_time(c, [f for f in wire if f.sensor == "lidar" or f.stamp_ns < death])
        wait_for(lambda: planner.n() >= 1, 5, "fused messages")
        time.sleep(window + 0.2)
        status = _status(c)
    lidar = [(f, t) for f, t in planner.messages if f.sensor == "lidar"]
    after = [f for f, _ in lidar if f.stamp_ns >= death]
    assert len(after) >= 25  # every lidar frame of the last 3 s answered
    waited = [(f.published_ns - f.received_ns) * 1e-9 for f in after]
    dying = [w for f, w in zip(after, waited, strict=True) if f.stamp_ns < death + 0.9e9]
    dead = [w for f, w in zip(after, waited, strict=True) if f.stamp_ns > death + 1.2e9]
    # Waited for the camera at most the window: the worker wakes at the window's end, and on a
    # loaded machine (2 cores, a flood test beside it) it has been seen to run 90 ms late;
    # waiting for the silence instead (silent_after_s) would show as 1 s.
    assert max(dying) <= window + 0.15, dying
    assert np.median(dead) < 0.05, dead  # then not at all: silent
    assert after[-1].sensor_state[1] is SensorCondition.SILENT
    vehicle = next(v for v in status.vehicles if v.vehicle == VEHICLE)
    camera = next(s for s in vehicle.sensors if s.sensor == "camera")
    assert camera.state is SensorCondition.SILENT and camera.idle_s is not None
    assert camera.idle_s > 2.0


def test_a_camera_frame_first_after_the_vehicles_link_was_down_is_tracked_not_flagged(
    tmp_path: Path,
) -> None:
    """The vehicle's link is down for 1.5 s (neither sensor sends), and the camera's frame
    is the first to come back. The lidar, silent since, is no clock to judge it by: the
    frame is tracked, not refused `sensor_flagged` with the camera's stamps said to run
    ahead of the lidar's (the lidar's standing used to be updated only after the frame)."""
    with _fusing(tmp_path, 0.3) as (c, planner, start):
        wire = frames(3.5, start)
        down, up = start + 1_000_000_000, start + 2_500_000_000
        back = [f for f in wire if f.stamp_ns >= up]
        first = next(f for f in back if f.sensor == "camera")
        # The lidar's frames stamped before the camera's go right after it.
        _in_real_time(c, [*(f for f in wire if f.stamp_ns < down), first])
        _in_real_time(c, [f for f in back if f is not first])
        wait_for(lambda: any(fr.stamp_ns == back[-1].stamp_ns for fr, _ in planner.messages),
                 5, "the last frame's message")  # fmt: skip
    assert [e for e in planner.errors if e.reason is ErrorReason.SENSOR_FLAGGED] == []
    answered = {(fr.sensor, fr.sensor_seq) for fr, _ in planner.messages}
    assert ("camera", first.seq) in answered
    after = [fr for fr, _ in planner.messages if fr.stamp_ns >= up]
    assert all(fr.sensor_state[1] is SensorCondition.OK for fr in after), after
