"""A fused sensor's publisher sends its mounting (``extrinsic``) with every frame, as a
DetectionFrame version 2, checked once when the publisher is made; without one its frames
stay version 1. Heard on a session of its own: no service needed."""

from __future__ import annotations

import threading
from collections.abc import Iterator

import numpy as np
import pytest
import zenoh

from simpletrack.client.publisher import Box, DetectionPublisher, check_extrinsic
from simpletrack.session import ZenohOptions, open_session
from simpletrack.wire import DecodedDetections, decode_detection_frame
from simpletrack.wire.keys import Keys

pytestmark = pytest.mark.zenoh

CAR = [Box(x=12, y=-3, z=0.8, yaw=0.1, l=4.5, w=1.9, h=1.6, score=0.9, cls="Car")]
# A rear radar: turned half a circle, 3.5 m behind the vehicle's origin.
REAR = np.array([[-1.0, 0, 0, -3.5], [0, -1.0, 0, 0], [0, 0, 1.0, 0.5], [0, 0, 0, 1.0]])
ROOF = np.array([[1.0, 0, 0, 1.5], [0, 1.0, 0, 0], [0, 0, 1.0, 1.8], [0, 0, 0, 1.0]])


@pytest.fixture
def session() -> Iterator[zenoh.Session]:
    s = open_session(ZenohOptions())
    yield s
    s.close()  # type: ignore[no-untyped-call]


def _heard(session: zenoh.Session, send: int, **kwargs: object) -> list[DecodedDetections]:
    got: list[bytes] = []
    done = threading.Event()

    def on_sample(sample: zenoh.Sample) -> None:
        got.append(sample.payload.to_bytes())
        if len(got) == send:
            done.set()

    sub = session.declare_subscriber(Keys().detections("veh01", "radar"), on_sample)
    with DetectionPublisher(session, "veh01", "radar", classes=("Car",), **kwargs) as pub:  # type: ignore[arg-type]
        pub.publish(CAR)
        if send > 1:
            pub.publish(CAR, extrinsic=ROOF)
        assert done.wait(5), f"heard {len(got)} of {send} frames"
    sub.undeclare()  # type: ignore[no-untyped-call]
    out = [decode_detection_frame(p) for p in got]
    assert all(isinstance(d, DecodedDetections) for d in out), out
    return [d for d in out if isinstance(d, DecodedDetections)]


def test_the_mounting_goes_with_every_frame_and_a_frame_may_override_it(
    session: zenoh.Session,
) -> None:
    first, second = _heard(session, 2, extrinsic=REAR)
    assert first.frame.schema_version == 2 and first.extrinsic is not None
    np.testing.assert_array_equal(first.extrinsic, REAR)
    assert second.extrinsic is not None
    np.testing.assert_array_equal(second.extrinsic, ROOF)


def test_without_a_mounting_frames_stay_version_1(session: zenoh.Session) -> None:
    (frame,) = _heard(session, 1)
    assert frame.frame.schema_version == 1 and frame.extrinsic is None


@pytest.mark.parametrize(
    ("bad", "match"),
    [
        (np.eye(3), "4x4"),
        (np.diag([2.0, 2.0, 2.0, 1.0]), "not a rigid transform"),
        (np.diag([1.0, 1.0, -1.0, 1.0]), "not a rigid transform"),
        (np.full((4, 4), np.nan), "NaN or inf"),
        (np.array([[1.0, 0, 0, 2e5], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]]), "translation"),
    ],
)
def test_a_bad_mounting_is_refused_when_the_publisher_is_made(
    session: zenoh.Session, bad: np.ndarray, match: str
) -> None:
    with pytest.raises(ValueError, match=match):
        DetectionPublisher(session, "veh01", "radar", classes=("Car",), extrinsic=bad)
    with pytest.raises(ValueError, match=match):
        check_extrinsic(bad)


def test_a_bad_override_is_refused_before_anything_is_sent(session: zenoh.Session) -> None:
    with DetectionPublisher(session, "veh01", "radar", classes=("Car",), extrinsic=REAR) as pub:
        with pytest.raises(ValueError, match="not a rigid transform"):
            pub.publish(CAR, extrinsic=np.diag([2.0, 2.0, 2.0, 1.0]))
        assert pub.sent == 0 and pub.next_seq == 0
