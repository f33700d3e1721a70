"""The one FrameError builder and the drop notice's refusal (no Zenoh needed for either)."""

from __future__ import annotations

from simpletrack.server.outbox import drop_notice, dropped, frame_error
from simpletrack.wire.codec import Rejection, decode_message, encode, pack
from simpletrack.wire.models import FrameError
from simpletrack.wire.reasons import ErrorReason


def test_a_drop_notice_names_the_frame_from_its_header() -> None:
    r = dropped(ErrorReason.DROPPED_QUEUE_FULL, pack({"seq": 7, "stamp_ns": 99, "boxes": b"?"}))
    assert r == Rejection(
        ErrorReason.DROPPED_QUEUE_FULL, None, "worker queue full (backpressure drop_oldest)", 7, 99
    )
    late = dropped(ErrorReason.DROPPED_SHUTDOWN, b"\xc1 garbage")
    assert (late.detail, late.seq, late.stamp_ns) == ("service shutting down", None, None)


def test_a_frame_error_round_trips_and_caps_field_and_detail() -> None:
    r = Rejection(ErrorReason.NON_FINITE, "f" * 300, "d" * 2000, 3, 4)
    err = frame_error("car-1", "lidar", r, instance="svc", received_ns=5)
    assert (err.seq, err.stamp_ns, err.reason, err.instance, err.received_ns) == (
        3, 4, ErrorReason.NON_FINITE, "svc", 5
    )  # fmt: skip
    assert err.field is not None and len(err.field) == 256 and len(err.detail) == 1024
    assert decode_message(encode(err), FrameError) == err


def test_a_drop_notice_names_every_frame_it_stands_for_and_round_trips() -> None:
    r = drop_notice(ErrorReason.DROPPED_QUEUE_FULL, [4, None, 6], 99)
    assert (r.seq, r.stamp_ns, r.field) == (4, 99, None) and r.detail.startswith("3 frames")
    err = frame_error("car-1", "lidar", r, instance="svc", received_ns=5, seqs=[4, None, 6])
    back = decode_message(encode(err), FrameError)
    assert not isinstance(back, Rejection) and back.seqs == [4, None, 6]


def test_an_error_without_seqs_is_encoded_as_before_the_field_existed() -> None:
    r = Rejection(ErrorReason.NON_FINITE, "pose", "nan", 3, 4)
    payload = encode(frame_error("car-1", "lidar", r, instance="svc", received_ns=5))
    assert b"seqs" not in payload
