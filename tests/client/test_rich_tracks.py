"""What a planner gets per track from a real service: with the default settings TrackFrame
version 2 (the filter's covariance, ages in seconds) and fleet-unique ids; with
``tracks_schema_version = 1`` the version-1 frame an old reader still decodes."""

from __future__ import annotations

import time
from collections.abc import Iterator
from pathlib import Path

import msgpack
import numpy as np
import pytest

from simpletrack.client.publisher import DetectionPublisher
from simpletrack.client.subscriber import TrackMessage, TrackSubscriber
from simpletrack.core.boxes import Boxes
from simpletrack.server.custody_machine import epoch_tag
from simpletrack.session import ZenohOptions, open_session
from simpletrack.wire.messages import TRACK_FRAME_V1
from tests.service_helpers import ServiceProcess, stamp, start_service, wait_for

pytestmark = pytest.mark.zenoh
CLASSES = ("Car", "Pedestrian", "Cyclist")


@pytest.fixture(scope="module")
def default_service(tmp_path_factory: pytest.TempPathFactory) -> Iterator[ServiceProcess]:
    svc = start_service(tmp_path_factory.mktemp("v2"), instance="rich-v2")
    yield svc
    svc.stop()


def cars(k: int) -> Boxes:
    """Two cars 8 m apart driving along +x at 10 m/s, frame k at 10 Hz."""
    params = [[10.0 + k, 8.0 * i, 0.8, 0.0, 4.0, 1.8, 1.6] for i in range(2)]
    return Boxes.from_arrays(params, [0.9] * 2, [0] * 2)


def _run(svc: ServiceProcess, vehicle: str, frames: int) -> tuple[list[TrackMessage], list[bytes]]:
    """The frames a TrackSubscriber yields, and the raw payloads, for ``frames`` frames."""
    options = ZenohOptions(connect=[svc.endpoint])
    raw: list[bytes] = []
    session = open_session(mode="peer", connect=[svc.endpoint])
    try:
        session.declare_subscriber(
            f"fleet/{vehicle}/lidar/tracks", lambda s: raw.append(s.payload.to_bytes())
        )
        with (
            TrackSubscriber.connect(options=options, vehicle=vehicle, sensor="lidar") as sub,
            DetectionPublisher.connect(vehicle, "lidar", classes=CLASSES, options=options) as pub,
        ):
            assert pub.wait_for_service(10)
            time.sleep(0.3)  # the subscriptions reach the service
            for k in range(frames):
                pub.publish(cars(k), stamp_ns=stamp(k))
            got: list[TrackMessage] = []
            deadline = time.monotonic() + 10
            while len(got) < frames and time.monotonic() < deadline:
                msg = sub.recv(timeout=0.2)
                if msg is not None:
                    got.append(msg)
            wait_for(lambda: len(raw) >= frames, 10, "raw track frames")
    finally:
        session.close()  # type: ignore[no-untyped-call]
    return got, raw


def test_default_service_publishes_version_3_with_covariance_ages_epoch_and_global_ids(
    default_service: ServiceProcess,
) -> None:
    got, raw = _run(default_service, "rich", 6)
    assert [m.seq for m in got] == list(range(6))
    assert {m.schema_version for m in got} == {3}
    # One custody all along: one epoch, the instance's tag in its low bits.
    assert len({m.epoch for m in got}) == 1 and got[0].epoch is not None
    assert got[0].epoch & 0xFFFF == epoch_tag(default_service.instance)
    first, last = got[0], got[-1]
    assert last.tracks.covariance is not None and last.tracks.age_s is not None
    cov = last.tracks.covariance_matrices()
    assert cov is not None and cov.shape == (2, 6, 6)
    np.testing.assert_array_equal(cov, cov.transpose(0, 2, 1))
    assert (np.linalg.eigvalsh(cov) > 0).all()
    born = first.tracks.covariance_matrices()
    assert born is not None
    # Five updates later the filter is surer of where each car is than at birth.
    assert (np.diagonal(cov[:, :3, :3], axis1=1, axis2=2) < born[:, 0, 0, None]).all()
    # Born on frame 0 and matched on every frame since: 0.5 s old, updated now.
    np.testing.assert_allclose(last.tracks.age_s, [0.5, 0.5], atol=1e-9)
    np.testing.assert_array_equal(last.tracks.time_since_update_s, [0.0, 0.0])  # type: ignore[arg-type]
    ids = last.tracks.id.tolist()
    assert last.global_ids == [f"rich/lidar/{i}" for i in ids]
    assert last.global_id(1) == f"rich/lidar/{ids[1]}"
    assert set(first.global_ids) == set(last.global_ids)  # the same tracks all along
    assert msgpack.unpackb(raw[-1], raw=False)["schema_version"] == 3


def test_tracks_schema_version_1_publishes_what_a_version_1_reader_takes(
    tmp_path: Path,
) -> None:
    svc = start_service(
        tmp_path, instance="rich-v1", env={"SIMPLETRACK_TRACKS_SCHEMA_VERSION": "1"}
    )
    try:
        got, raw = _run(svc, "old", 3)
    finally:
        svc.stop()
    assert [m.seq for m in got] == [0, 1, 2]
    assert {m.schema_version for m in got} == {1}
    t = got[-1].tracks
    assert t.covariance is None and t.age_s is None and t.time_since_update_s is None
    assert got[-1].global_ids == [f"old/lidar/{i}" for i in t.id.tolist()]
    for payload in raw:  # the version-1 field table takes every one of them as it is
        frame = TRACK_FRAME_V1(msgpack.unpackb(payload, raw=False))
        assert frame.schema_version == 1 and frame.tracks.age_s is None


def test_an_unknown_tracks_schema_version_is_refused_at_startup(tmp_path: Path) -> None:
    with pytest.raises(AssertionError, match="tracks_schema_version"):
        start_service(tmp_path, instance="rich-v4", env={"SIMPLETRACK_TRACKS_SCHEMA_VERSION": "4"})
