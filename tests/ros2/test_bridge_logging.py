"""The bridge's counting and logging, in process on a real (unconnected) Zenoh session: a label
without a class is logged once, refusals at most once per interval, and nothing stops it."""

from __future__ import annotations

import logging
from collections.abc import Iterator

import pytest

from simpletrack.ros2.bridge import Ros2Bridge
from simpletrack.ros2.labels import label_map
from simpletrack.ros2.layout import Layout, topic_keys
from simpletrack.session import open_session
from tests.ros2 import rosmsgs as R

pytestmark = pytest.mark.zenoh


@pytest.fixture
def bridge() -> Iterator[Ros2Bridge]:
    session = open_session(mode="peer")
    b = Ros2Bridge(
        session,
        topic_keys(Layout.ROS2DDS),
        vehicle="veh-log",
        sensor="lidar",
        labels=label_map("kitti"),
        classes=("Car", "Pedestrian", "Cyclist"),
        log_interval_s=3600,
    )
    yield b
    b.close()
    session.close()  # type: ignore[no-untyped-call]


def _truck_and_car(k: int) -> bytes:
    truck = R.detected_object(R.FIXTURE[0], classes=R.classification((2, 0.9)))
    bus = R.detected_object(R.FIXTURE[0], classes=R.classification((3, 0.9)))
    return R.serialize(R.detected_objects([truck, bus, R.detected_object(R.FIXTURE[2])], nanosec=k))


def test_a_label_without_a_class_is_logged_once_and_counted_every_time(
    bridge: Ros2Bridge, caplog: pytest.LogCaptureFixture
) -> None:
    caplog.set_level(logging.WARNING, "simpletrack.ros2.bridge")
    seqs = [bridge.handle(_truck_and_car(k)) for k in range(5)]
    assert seqs == [0, 1, 2, 3, 4]  # every frame still went out, with the car
    assert bridge.stats.unknown_labels == {2: 5, 3: 5}
    assert bridge.stats.skipped == {"unknown_label": 10}
    lines = [r.getMessage() for r in caplog.records]
    assert sum("label 2 maps to no class" in m for m in lines) == 1
    assert sum("label 3 maps to no class" in m for m in lines) == 1
    assert "kitti: CAR=Car, BICYCLE=Cyclist, PEDESTRIAN=Pedestrian" in lines[0]


def test_refusals_are_logged_once_per_interval_and_counted(
    bridge: Ros2Bridge, caplog: pytest.LogCaptureFixture
) -> None:
    caplog.set_level(logging.WARNING, "simpletrack.ros2.bridge")
    for junk in (b"", b"\x00\x01\x00\x00", b"\xff" * 100, R.fixture_cdr()[:50]):
        assert bridge.handle(junk) is None
    assert bridge.handle(R.fixture_cdr()) == 0  # and the next good frame goes out
    assert bridge.stats.refused == {"bad_cdr": 4}
    assert bridge.stats.published == 1
    refusals = [r.getMessage() for r in caplog.records if "frame refused" in r.getMessage()]
    assert len(refusals) == 1
    assert "shorter than the CDR header" in refusals[0]


def test_non_box_and_unclassified_objects_are_logged_by_reason(
    bridge: Ros2Bridge, caplog: pytest.LogCaptureFixture
) -> None:
    caplog.set_level(logging.WARNING, "simpletrack.ros2.bridge")
    objs = [
        R.detected_object(R.FIXTURE[0], kind=2),
        R.detected_object(R.FIXTURE[1], classes=[]),
        R.detected_object(R.FIXTURE[2]),
    ]
    for k in range(3):
        bridge.handle(R.serialize(R.detected_objects(objs, nanosec=k)))
    assert bridge.stats.skipped == {"not_a_box": 3, "no_classification": 3}
    lines = [r.getMessage() for r in caplog.records]
    assert sum("not_a_box" in m for m in lines) == 1
    assert sum("no_classification" in m for m in lines) == 1
