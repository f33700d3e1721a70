"""Item 8: absurd but finite boxes (3.4e38 m, a 1 km truck, 1e4 m/s, a pose on the Moon) are
refused on the errors key with a reason and the field, and the sensor keeps tracking."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from simpletrack.wire import BoxArrays, ErrorReason
from tests.service_helpers import client, metric, moving_cars, stamp, start_service, wait_for

pytestmark = pytest.mark.zenoh


def _absurd(k: int) -> tuple[BoxArrays, np.ndarray | None, str]:
    """Frame k's cars with one value pushed past its bound, the pose if any, and the field."""
    good = moving_cars(k)
    kind = k % 5
    if kind == 0:
        center = good.center.copy()
        center[1, 0] = 3.4e38
        return replace(good, center=center), None, "boxes.center"
    if kind == 1:
        size = good.size.copy()
        size[2] = [1000.0, 2.0, 2.0]
        return replace(good, size=size), None, "boxes.size"
    if kind == 2:
        return replace(good, yaw=np.full(3, 1e30, np.float32)), None, "boxes.yaw"
    if kind == 3:
        velocity = np.zeros((3, 2), np.float32)
        velocity[0] = [1e4, 0.0]
        return replace(good, velocity=velocity), None, "boxes.velocity"
    pose = np.eye(4)
    pose[:3, 3] = [3.8e8, 0.0, 0.0]  # the Moon
    return good, pose, "pose"


def test_implausible_boxes_are_refused_with_field_and_the_sensor_keeps_tracking(
    tmp_path: Path,
) -> None:
    svc = start_service(tmp_path)
    sensor = "veh/absurd"
    good_before, bad, good_after = range(0, 4), range(4, 14), range(14, 20)
    try:
        with client(svc.endpoint) as cli:
            for k in good_before:
                cli.send("veh", "absurd", seq=k, stamp_ns=stamp(k), boxes=moving_cars(k))
            wait_for(lambda: cli.received.n_tracks(sensor) == len(good_before), 20, "first")
            fields = {}
            for k in bad:
                boxes, pose, fields[k] = _absurd(k)
                cli.send("veh", "absurd", seq=k, stamp_ns=stamp(k), boxes=boxes, pose=pose)
            wait_for(lambda: cli.received.n_errors(sensor) == len(bad), 20, "the refusals")
            for k in good_after:
                cli.send("veh", "absurd", seq=k, stamp_ns=stamp(k), boxes=moving_cars(k))
            want = len(good_before) + len(good_after)
            wait_for(lambda: cli.received.n_tracks(sensor) == want, 20, "the good frames after")
            errors = cli.received.errors[sensor]
            tracks = cli.received.tracks[sensor]
        values = svc.metrics()
    finally:
        assert svc.stop() == 0

    assert [(e.seq, e.reason, e.field) for e in errors] == [
        (k, ErrorReason.INVALID_VALUE, fields[k]) for k in bad
    ]
    assert all("over" in e.detail for e in errors)
    assert metric(values, "simpletrack_frames_rejected_total", reason="invalid_value") == len(bad)
    assert metric(values, "simpletrack_tracker_resets_total", reason="gap") == 0
    # Every track frame finite, and the same three cars keep their ids across the refusals.
    assert [f.seq for f, _ in tracks] == [*good_before, *good_after]
    for _, t in tracks:
        for name in ("center", "size", "yaw", "score", "velocity"):
            assert np.isfinite(getattr(t, name)).all(), name
    assert {int(i) for i in tracks[-1][1].id} <= {int(i) for _, t in tracks[:-1] for i in t.id}
    assert len(tracks[-1][1]) == 3
    assert "RuntimeWarning" not in svc.log_path.read_text()
