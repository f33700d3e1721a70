"""Item 8: a track frame never carries a non-finite number. In-bounds but extreme frames
(centres and pose translations at +-1e5 m, sizes from 1e-45 to 100 m, yaws at +-1e4 rad,
+-200 m/s, scores of +-1e300, stamp steps from 1 ns to years) go through a real service; every
frame is tracked and every track frame decodes and is finite. The guard that would stop a
non-finite frame, and numpy's warnings, are checked on their own below."""

from __future__ import annotations

import threading
import warnings
from pathlib import Path

import numpy as np
import numpy.typing as npt
import pytest
import zenoh

from simpletrack.core.config import preset
from simpletrack.server.finite import FloatingPointErrors, first_non_finite, non_finite_refusal
from simpletrack.wire import BoxArrays, ErrorReason, Rejection, TrackArrays, decode_track_frame
from tests.service_helpers import client, metric, start_service, wait_for

FLOATS = ("center", "size", "yaw", "score", "velocity")
T0 = 1_700_000_000_000_000_000


def _rotation(yaw: float, translation: npt.NDArray[np.float64]) -> npt.NDArray[np.float64]:
    c, s = np.cos(yaw), np.sin(yaw)
    pose = np.eye(4)
    pose[:2, :2] = [[c, -s], [s, c]]
    pose[:3, 3] = translation
    return pose


def extreme_frames(
    classes: tuple[str, ...], n_frames: int, seed: int, long_gaps: bool
) -> list[tuple[int, BoxArrays, npt.NDArray[np.float64] | None]]:
    """(stamp_ns, boxes, pose) of frames at the edges of the bounds. Half the frames carry the
    same objects jumping back and forth (so tracks live, match and build up velocity and
    covariance), half are scattered anywhere in bounds."""
    rng = np.random.default_rng(seed)
    n = 5
    home = rng.uniform(-1e5, 1e5, (n, 3))
    t, frames = T0, []
    for k in range(n_frames):
        if k % 2 == 0:
            centre = home + rng.choice([0.0, 40.0, -60.0]) * (k % 4 == 0)
        else:
            centre = rng.choice([-1e5, 1e5, 0.0], (n, 3)) + rng.normal(0.0, 1.0, (n, 3))
        size = np.full((n, 3), rng.choice([100.0, 1.0, 1e-3, 1e-30, 1e-45]))
        size[rng.integers(0, n)] = rng.uniform(1e-6, 100.0, 3)
        yaw = rng.choice([1e4, -1e4, 0.0, np.pi, -np.pi], n)
        velocity = rng.choice([200.0, -200.0, 0.0], (n, 2)) if k % 3 else None
        boxes = BoxArrays(
            classes=classes,
            class_index=rng.integers(0, len(classes), n).astype(np.int32) * (k % 2),
            center=np.clip(centre, -1e5, 1e5).astype(np.float32),
            size=np.clip(size, 0.0, 100.0).astype(np.float32),
            yaw=yaw.astype(np.float32),
            score=rng.choice([1e300, -1e300, 0.0, 0.9, 5e-324, 1.0], n),
            velocity=None if velocity is None else velocity.astype(np.float32),
        )
        pose = None
        if k % 5 == 4:
            pose = _rotation(rng.uniform(-np.pi, np.pi), rng.choice([1e5, -1e5, 0.0], 3))
        steps = [1, 1_000, 100_000_000, 4_900_000_000]
        if long_gaps:
            steps.append(100_000_000_000_000_000)  # about 3 years
        step = int(rng.choice(steps))
        t = t + step if t + step < 2**63 else t + 1
        frames.append((t, boxes, pose))
    return frames


@pytest.mark.zenoh
@pytest.mark.parametrize(
    ("preset_name", "reset_gap_s"),
    [("kitti", "5"), ("nuscenes", "1e10")],
    ids=["kitti-kalman", "nuscenes-years-between-frames"],
)
def test_in_bounds_extreme_frames_give_finite_track_frames_only(
    tmp_path: Path, preset_name: str, reset_gap_s: str
) -> None:
    classes = preset(preset_name).class_names
    frames = extreme_frames(classes, 160, seed=8, long_gaps=reset_gap_s != "5")
    env = {
        "SIMPLETRACK_PRESET": preset_name,
        "SIMPLETRACK_RESET_GAP_S": reset_gap_s,
        "SIMPLETRACK_QUEUE_SIZE": "1000",  # a burst of frames, none shed
    }
    svc = start_service(tmp_path, env=env)
    raw: list[bytes] = []
    lock = threading.Lock()

    def keep(sample: zenoh.Sample) -> None:
        with lock:
            raw.append(sample.payload.to_bytes())

    try:
        with client(svc.endpoint) as cli:
            sub = cli.session.declare_subscriber("fleet/veh/edge/tracks", keep)
            for k, (stamp_ns, boxes, pose) in enumerate(frames):
                cli.send("veh", "edge", seq=k, stamp_ns=stamp_ns, boxes=boxes, pose=pose)
            answered = lambda: len(raw) + cli.received.n_errors("veh/edge")  # noqa: E731
            wait_for(lambda: answered() == len(frames), 60, "every frame answered")
            errors = list(cli.received.errors.get("veh/edge", []))
            sub.undeclare()  # type: ignore[no-untyped-call]
        values = svc.metrics()
    finally:
        assert svc.stop() == 0

    assert [(e.seq, e.reason, e.field, e.detail) for e in errors] == []
    decoded = [decode_track_frame(p) for p in raw]
    refused = [d for d in decoded if isinstance(d, Rejection)]
    assert refused == []
    tracks = [t for d in decoded if not isinstance(d, Rejection) for t in [d[1]]]
    assert sum(len(t) for t in tracks) > len(frames), "the frames should make live tracks"
    for t in tracks:
        for name in FLOATS:
            assert np.isfinite(getattr(t, name)).all(), name
    assert metric(values, "simpletrack_tracker_resets_total", reason="non_finite") == 0
    assert "RuntimeWarning" not in svc.log_path.read_text()


def _tracks(center: list[list[float]]) -> TrackArrays:
    n = len(center)
    ints = np.zeros(n, np.int32)
    return TrackArrays(
        classes=("Car",),
        id=np.arange(n, dtype=np.int64),
        class_index=ints,
        center=np.array(center, np.float32),
        size=np.ones((n, 3), np.float32),
        yaw=np.zeros(n, np.float32),
        score=np.ones(n),
        velocity=np.zeros((n, 3), np.float32),
        state=ints,
        hits=ints,
        age=ints,
        time_since_update=ints,
    )


def test_a_track_frame_with_inf_is_refused_as_internal_error_naming_column_and_row() -> None:
    assert non_finite_refusal(_tracks([[1.0, 2.0, 3.0]]), seq=4, stamp_ns=5) is None
    assert first_non_finite(_tracks([])) is None
    r = non_finite_refusal(_tracks([[1.0, 2.0, 3.0], [np.inf, 0.0, 0.0]]), seq=4, stamp_ns=5)
    assert r is not None
    assert (r.reason, r.field, r.seq, r.stamp_ns) == (
        ErrorReason.INTERNAL_ERROR,
        "tracks.center",
        4,
        5,
    )
    assert "row 1" in r.detail and "reset" in r.detail
    # Finite values whose sum overflows float32 are finite all the same; a NaN among them is
    # still found, at its row.
    big = [[3e38, 3e38, 3e38], [3e38, 3e38, 3e38]]
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # nor a RuntimeWarning on stderr, outside the log
        assert first_non_finite(_tracks(big)) is None
    assert first_non_finite(_tracks([*big, [0.0, np.nan, 0.0]])) == ("center", 2)


def test_numpy_floating_point_errors_are_recorded_not_printed(
    capfd: pytest.CaptureFixture[str],
) -> None:
    fp = FloatingPointErrors()
    with fp:
        big = np.array([3e38], np.float64).astype(np.float32) * np.float32(10)
    with fp:
        nan = np.zeros(1) / np.zeros(1)
    assert np.isinf(big).all() and np.isnan(nan).all(), "results as with numpy's default"
    assert fp.kinds == ["overflow", "invalid value"]
    assert capfd.readouterr().err == ""
    with np.errstate(over="ignore"):  # the caller's own settings come back afterwards
        with fp:
            pass
        np.array([3e38], np.float32) * np.float32(10)
    assert fp.kinds == ["overflow", "invalid value"]


def test_a_fused_frames_own_columns_are_guarded_too() -> None:
    """A vehicle's message carries existence beside a sensor's columns: the same guard."""
    from dataclasses import replace

    fused = replace(
        _tracks([[1.0, 2.0, 3.0], [4.0, 5.0, 6.0]]),
        existence=np.array([0.5, np.nan]),
        sensor_stamp_ns=np.zeros((2, 2), np.int64),
    )
    assert first_non_finite(fused) == ("existence", 1)
    assert non_finite_refusal(replace(fused, existence=np.array([0.5, 1.0])), 1, 2) is None
