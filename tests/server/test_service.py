"""``simpletrack serve`` end to end over Zenoh: tracks, errors, metrics, queries, KITTI parity."""

from __future__ import annotations

import threading
from collections.abc import Iterator
from pathlib import Path

import msgpack
import numpy as np
import pytest

from simpletrack.core.tracker import Tracker
from simpletrack.wire import (
    BoxArrays,
    ErrorReason,
    Rejection,
    SensorSnapshot,
    ServiceStatus,
    WireTrackState,
    decode_message,
    encode_detection_frame,
)
from tests.service_helpers import (
    DATA,
    Client,
    ServiceProcess,
    client,
    metric,
    moving_cars,
    stamp,
    start_service,
    wait_for,
)

pytestmark = pytest.mark.zenoh
MAX_BOXES = 400


@pytest.fixture(scope="module")
def service(tmp_path_factory: pytest.TempPathFactory) -> Iterator[ServiceProcess]:
    tmp = tmp_path_factory.mktemp("svc")
    svc = start_service(
        tmp,
        "--workers",
        "2",
        env={"SIMPLETRACK_MAX_BOXES": str(MAX_BOXES), "SIMPLETRACK_RESET_GAP_S": "3"},
    )
    yield svc
    assert svc.stop() == 0
    events = [e["event"] for e in svc.logs()]
    assert "service_stopped" in events


@pytest.fixture(scope="module")
def cli(service: ServiceProcess) -> Iterator[Client]:
    c = Client(service.endpoint)
    yield c
    c.close()


def run_sensor(cli: Client, vehicle: str, sensor: str, frames: int, first: int = 0) -> None:
    for k in range(first, first + frames):
        cli.send(vehicle, sensor, seq=k, stamp_ns=stamp(k), boxes=moving_cars(k))


def test_every_frame_gets_tracks_with_stable_ids(cli: Client) -> None:
    run_sensor(cli, "car-1", "lidar", 12)
    wait_for(lambda: cli.received.n_tracks("car-1/lidar") == 12, 20, "12 track frames")
    frames = cli.received.tracks["car-1/lidar"]
    assert [f.seq for f, _ in frames] == list(range(12))
    assert [f.stamp_ns for f, _ in frames] == [stamp(k) for k in range(12)]
    ids = [sorted(t.id.tolist()) for _, t in frames]
    assert ids == [[0, 1, 2]] * 12
    last_frame, last = frames[-1]
    assert last_frame.frame_id == "lidar" and last_frame.instance == "svc-test"
    assert last_frame.received_ns <= last_frame.published_ns
    assert (last.state == WireTrackState.CONFIRMED).all()
    assert set(last.classes) == {"Car", "Pedestrian", "Cyclist"}
    np.testing.assert_allclose(np.sort(last.center[:, 1]), [0.0, 10.0, 20.0], atol=0.05)
    np.testing.assert_allclose(last.velocity[:, 0], 10.0, atol=0.5)  # filter learnt 10 m/s
    assert cli.received.n_errors("car-1/lidar") == 0


def test_two_sensors_are_tracked_independently_and_concurrently(cli: Client) -> None:
    # Same objects, two vehicles: each stream has its own tracker (ids from 0 in both).
    threads = [
        threading.Thread(target=run_sensor, args=(cli, vehicle, "front", 10))
        for vehicle in ("car-2", "car-3")
    ]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    for name in ("car-2/front", "car-3/front"):
        wait_for(lambda name=name: cli.received.n_tracks(name) == 10, 20, name)
        frames = cli.received.tracks[name]
        assert [f.seq for f, _ in frames] == list(range(10)), name
        assert all(sorted(t.id.tolist()) == [0, 1, 2] for _, t in frames), name


def _good(k: int) -> bytes:
    return encode_detection_frame(
        vehicle="car-4", sensor="bad", seq=k, stamp_ns=stamp(k), frame_id="l", boxes=moving_cars(k)
    )


def _mutate(k: int, path: str, value: object) -> bytes:
    obj = msgpack.unpackb(_good(k), raw=False)
    target = obj
    *parents, last = path.split(".")
    for p in parents:
        target = target[p]
    if value is None:
        del target[last]
    else:
        target[last] = value
    return msgpack.packb(obj, use_bin_type=True)


NAN = np.array([[np.nan, 0, 0], [0, 0, 0], [0, 0, 0]], np.float32).tobytes()
FLAT = np.array([[4, 2, 0], [4, 2, 1], [4, 2, 1]], np.float32).tobytes()
TOO_MANY = moving_cars(0, n=MAX_BOXES + 1)


def test_bad_inputs_are_reported_while_other_sensors_carry_on(
    service: ServiceProcess, cli: Client
) -> None:
    # (payload, reason, field, seq the error names). Frames 0-1 are good and set the
    # sensor's last seq/stamp to 1 / stamp(1); each bad one must leave them unchanged.
    cases: list[tuple[bytes, ErrorReason, str | None, int | None]] = [
        (b"\x93\x01\x02", ErrorReason.MALFORMED, "payload", None),
        (_mutate(2, "schema_version", 9), ErrorReason.WRONG_VERSION, "schema_version", 2),
        (_mutate(2, "frame_id", None), ErrorReason.MISSING_FIELD, "frame_id", 2),
        (_mutate(2, "colour", "red"), ErrorReason.EXTRA_FIELD, "colour", 2),
        (_mutate(2, "boxes.yaw", b"\0" * 4), ErrorReason.COLUMN_LENGTH, "boxes.yaw", 2),
        (_mutate(2, "boxes.center", NAN), ErrorReason.NON_FINITE, "boxes.center", 2),
        (_mutate(2, "boxes.size", FLAT), ErrorReason.NON_POSITIVE_SIZE, "boxes.size", 2),
        (_mutate(2, "boxes.classes", ["Tram"]), ErrorReason.UNKNOWN_CLASS, "boxes.classes.0", 2),
        (
            encode_detection_frame(
                vehicle="car-4",
                sensor="bad",
                seq=2,
                stamp_ns=stamp(2),
                frame_id="l",
                boxes=TOO_MANY,
            ),
            ErrorReason.TOO_LARGE,
            "boxes.count",
            2,
        ),
        (_mutate(2, "vehicle", "car-5"), ErrorReason.KEY_MISMATCH, "vehicle", 2),
        (_mutate(1, "stamp_ns", stamp(1)), ErrorReason.DUPLICATE_SEQ, "seq", 1),
        (_mutate(2, "stamp_ns", stamp(1)), ErrorReason.OUT_OF_ORDER, "stamp_ns", 2),
        (_mutate(2, "stamp_ns", stamp(0)), ErrorReason.OUT_OF_ORDER, "stamp_ns", 2),
        (_mutate(1, "stamp_ns", stamp(0)), ErrorReason.DUPLICATE_SEQ, "seq", 1),
    ]
    before = service.metrics()
    cli.put("car-4", "bad", _good(0))
    cli.put("car-4", "bad", _good(1))
    good_sensor = "car-6/lidar"
    for i, (payload, *_) in enumerate(cases):
        cli.put("car-4", "bad", payload)
        cli.send("car-6", "lidar", seq=i, stamp_ns=stamp(i), boxes=moving_cars(i))
    cli.put("car-4", "bad", _good(2))  # the sensor still works after all that

    wait_for(lambda: cli.received.n_tracks("car-4/bad") == 3, 20, "3 good frames of car-4")
    wait_for(lambda: cli.received.n_tracks(good_sensor) == len(cases), 20, "the good sensor")
    wait_for(lambda: cli.received.n_errors("car-4/bad") == len(cases), 20, "every error")
    errors = cli.received.errors["car-4/bad"]
    got = [(e.reason, e.field, e.seq) for e in errors]
    assert got == [(r, f, s) for _, r, f, s in cases]
    assert all(e.instance == "svc-test" and e.detail for e in errors)
    assert [f.seq for f, _ in cli.received.tracks["car-4/bad"]] == [0, 1, 2]
    assert cli.received.n_errors(good_sensor) == 0

    after = service.metrics()
    for reason in {r for _, r, _, _ in cases}:
        want = sum(1 for _, r, _, _ in cases if r is reason)
        name = "simpletrack_frames_rejected_total"
        assert metric(after, name, reason=reason) - metric(before, name, reason=reason) == want


def test_metrics_move_by_the_frames_sent(service: ServiceProcess, cli: Client) -> None:
    before = service.metrics()
    run_sensor(cli, "car-7", "lidar", 8)
    wait_for(lambda: cli.received.n_tracks("car-7/lidar") == 8, 20, "8 frames")
    wait_for(
        lambda: (
            metric(service.metrics(), "simpletrack_frames_tracked_total")
            - metric(before, "simpletrack_frames_tracked_total")
            == 8
        ),
        5,
        "the tracked counter",
    )
    after = service.metrics()

    def delta(name: str, **labels: str) -> float:
        return metric(after, name, **labels) - metric(before, name, **labels)

    assert delta("simpletrack_frames_received_total") == 8
    assert delta("simpletrack_frames_tracked_total") == 8
    for stage in ("queue", "decode", "track", "publish"):
        assert delta("simpletrack_stage_seconds_count", stage=stage) == 8, stage
        assert delta("simpletrack_stage_seconds_sum", stage=stage) > 0, stage
    assert delta("simpletrack_end_to_end_seconds_count") == 8
    assert delta("simpletrack_service_latency_seconds_count") == 8
    assert sum(v for k, v in after.items() if k.startswith("simpletrack_frames_rejected")) == sum(
        v for k, v in before.items() if k.startswith("simpletrack_frames_rejected")
    )
    assert metric(after, "simpletrack_active_sensors") >= 1
    assert metric(after, "simpletrack_active_tracks") >= 3
    assert metric(after, "simpletrack_queue_depth") == 0
    assert any(k.startswith("simpletrack_build_info{") for k in after)
    assert "simpletrack_snapshot_age_seconds" in after
    assert service.http("/healthz")[0] == 200 and service.http("/readyz")[0] == 200


def test_a_stamp_gap_resets_the_tracker_without_reusing_ids(
    service: ServiceProcess, cli: Client
) -> None:
    before = service.metrics()
    run_sensor(cli, "car-8", "lidar", 4)
    # 10 s of silence (reset_gap_s is 3 here): a new tracker, ids above all earlier ones.
    for k in range(100, 103):
        cli.send("car-8", "lidar", seq=k, stamp_ns=stamp(k), boxes=moving_cars(k))
    wait_for(lambda: cli.received.n_tracks("car-8/lidar") == 7, 20, "7 frames")
    ids = [sorted(t.id.tolist()) for _, t in cli.received.tracks["car-8/lidar"]]
    assert ids[:4] == [[0, 1, 2]] * 4
    assert ids[4:] == [[3, 4, 5]] * 3
    name = "simpletrack_tracker_resets_total"
    assert metric(service.metrics(), name, reason="gap") - metric(before, name, reason="gap") == 1


def test_status_and_snapshot_queries(cli: Client) -> None:
    run_sensor(cli, "car-9", "lidar", 3)
    wait_for(lambda: cli.received.n_tracks("car-9/lidar") == 3, 20, "3 frames")
    [raw] = cli.get("fleet/@simpletrack/*/status")
    status = decode_message(raw, ServiceStatus)
    assert not isinstance(status, Rejection), status
    assert status.instance == "svc-test" and status.ready and status.preset == "kitti"
    mine = [s for s in status.sensors if (s.vehicle, s.sensor) == ("car-9", "lidar")]
    assert len(mine) == 1 and mine[0].last_seq == 2 and mine[0].frames == 3

    [raw] = cli.get("fleet/@simpletrack/svc-test/snapshot/car-9/lidar")
    snap = decode_message(raw, SensorSnapshot)
    assert not isinstance(snap, Rejection), snap
    assert (snap.last_seq, snap.stamp_origin_ns, snap.frames) == (2, stamp(0), 3)
    assert snap.tracker is not None
    tracker = Tracker.from_bytes(snap.tracker)
    assert tracker.frame_count == 3 and snap.id_next == 3

    everything = cli.get("fleet/@simpletrack/svc-test/snapshot/**")
    assert len(everything) >= 2  # car-9 and the sensors of earlier tests
    assert cli.get("fleet/@simpletrack/svc-test/snapshot/nobody/here") == []


# --- streaming equals batch on real data ----------------------------------------------------

KITTI = DATA / "kitti"
SEQ = "0003"


@pytest.mark.data
@pytest.mark.skipif(
    not (KITTI / "labels" / f"{SEQ}.txt").is_file(), reason="needs ../shared/data/kitti"
)
def test_kitti_sequence_through_zenoh_equals_the_offline_core(cli: Client) -> None:
    from simpletrack.core.boxes import Boxes
    from simpletrack.core.config import preset
    from simpletrack.core.frames import Frame
    from simpletrack.datasets.kitti import KITTI_CLASSES, load_sequence
    from simpletrack.wire.convert import tracks_to_wire

    config = preset("kitti")
    frames = load_sequence(KITTI, SEQ, config, KITTI_CLASSES)
    names = config.class_names
    batch = Tracker(config)
    expected = []
    for k, f in enumerate(frames):
        p = f.boxes.params.astype(np.float32)  # what the wire carries
        boxes = BoxArrays(
            classes=names,
            class_index=f.boxes.cls.astype(np.int32),
            center=p[:, 0:3],
            size=p[:, 4:7],
            yaw=p[:, 3],
            score=f.boxes.score.astype(np.float32),
        )
        cli.send("kitti", SEQ, seq=k, stamp_ns=stamp(k), boxes=boxes, frame_id="cam")
        # Batch: the same float32 inputs and the same stamps the service computes.
        params = np.concatenate([p[:, 0:3], p[:, 3:4], p[:, 4:7]], axis=1).astype(np.float64)
        out = batch.step(
            Frame(
                Boxes.from_arrays(params, boxes.score, boxes.class_index),
                (stamp(k) - stamp(0)) * 1e-9,
            )
        )
        expected.append(tracks_to_wire(out, 0, names))
        if k % 16 == 15:  # lockstep in small bursts keeps the service queue short
            wait_for(lambda k=k: cli.received.n_tracks(f"kitti/{SEQ}") == k + 1, 30, "tracks")
    wait_for(lambda: cli.received.n_tracks(f"kitti/{SEQ}") == len(frames), 30, "all tracks")
    got = cli.received.tracks[f"kitti/{SEQ}"]
    assert [f.seq for f, _ in got] == list(range(len(frames)))
    assert sum(len(t) for _, t in got) > 500  # the sequence really produced tracks
    for k, ((_, g), e) in enumerate(zip(got, expected, strict=True)):
        for name in ("id", "class_index", "center", "size", "yaw", "score", "velocity", "state"):
            np.testing.assert_array_equal(getattr(g, name), getattr(e, name), err_msg=f"{k} {name}")


def test_status_reports_the_default_preset_s_config(cli: Client) -> None:
    from simpletrack.core.config import preset
    from simpletrack.server.settings import config_digest

    [raw] = cli.get("fleet/@simpletrack/svc-test/status")
    status = decode_message(raw, ServiceStatus)
    assert not isinstance(status, Rejection), status
    assert status.config_digest == config_digest(preset("kitti"))


def test_tracker_options_from_flags_and_environment_reach_the_running_tracker(
    tmp_path: Path,
) -> None:
    from simpletrack.core.config import MotionModel, OutputPolicy, preset
    from simpletrack.server.settings import config_digest

    svc = start_service(
        tmp_path,
        "--preset",
        "wod",
        "--motion",
        "constant_velocity",
        "--output",
        "paper",
        env={"SIMPLETRACK_TRACKER__COAST_SCORE_DECAY": "0.5"},
        instance="svc-options",
    )
    try:
        with client(svc.endpoint) as c:
            [raw] = c.get("fleet/@simpletrack/svc-options/status")
    finally:
        assert svc.stop() == 0
    status = decode_message(raw, ServiceStatus)
    assert not isinstance(status, Rejection), status
    want = preset("wod").with_overrides(
        motion=MotionModel.CONSTANT_VELOCITY, output=OutputPolicy.PAPER, coast_score_decay=0.5
    )
    assert (status.preset, status.config_digest) == ("wod", config_digest(want))


def test_serve_help_lists_the_flags() -> None:
    import subprocess
    import sys

    out = subprocess.run(
        [sys.executable, "-m", "simpletrack.cli.main", "serve", "--help"],
        capture_output=True,
        text=True,
        cwd=Path(__file__).resolve().parents[2],
        check=True,
    ).stdout
    for flag in ("--mode", "--listen", "--connect", "--metrics-port", "--state-dir", "--config"):
        assert flag in out
    for flag in (
        "--motion",
        "--output",
        "--vertical-overlap",
        "--tie-order",
        "--coast-score-decay",
    ):
        assert flag in out


def test_with_a_pose_tracks_come_back_in_the_world_frame(cli: Client) -> None:
    pose = np.eye(4)
    pose[:3, :3] = [[0, -1, 0], [1, 0, 0], [0, 0, 1]]  # sensor yawed 90 degrees
    pose[:3, 3] = [100.0, -50.0, 2.0]
    for k in range(3):
        cli.send("car-10", "lidar", seq=k, stamp_ns=stamp(k), boxes=moving_cars(k), pose=pose)
    wait_for(lambda: cli.received.n_tracks("car-10/lidar") == 3, 20, "3 frames")
    frame, tracks = cli.received.tracks["car-10/lidar"][-1]
    assert frame.frame_id == "world" and frame.pose == pose.reshape(16).tolist()
    local = moving_cars(2).center.astype(np.float64)
    world = local @ pose[:3, :3].T + pose[:3, 3]
    got = tracks.center[np.argsort(tracks.center[:, 0])]
    np.testing.assert_allclose(got, world[np.argsort(world[:, 0])], atol=0.05)
    np.testing.assert_allclose(tracks.yaw, np.pi / 2, atol=1e-3)
