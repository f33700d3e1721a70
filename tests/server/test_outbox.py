"""The one FrameError builder and the drop notice's refusal (no Zenoh needed for either)."""

from __future__ import annotations

import dataclasses

import pytest

from simpletrack.server.outbox import drop_notice, dropped, frame_error, missed_notice
from simpletrack.wire import models
from simpletrack.wire.codec import Rejection, decode_message, encode, pack
from simpletrack.wire.messages import INT64_MAX, FrameError
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


# Refusals as the workers build them, each with what makes it differ from the others.
REFUSALS = [
    frame_error("car-1", "lidar", dropped(ErrorReason.MALFORMED, b"\xc1"), "svc", 5),  # no seq
    frame_error(
        "car-1", "lidar", Rejection(ErrorReason.NON_FINITE, "f" * 300, "d" * 2000, 3, 4), "svc", 5
    ),  # capped field and detail
    frame_error(
        "v.2_x-y",
        "s" * 64,
        Rejection(ErrorReason.OUT_OF_ORDER, "stamp_ns", "stamp é 😀 ≤ last", INT64_MAX, 0),
        "svc-a",
        INT64_MAX,
    ),  # names at their edges, unicode, int64 bounds
    frame_error(
        "car-1",
        "lidar",
        drop_notice(ErrorReason.DROPPED_QUEUE_FULL, [4, None, 6], 99),
        "svc",
        5,
        seqs=[4, None, 6],
    ),  # a drop notice names its frames
    frame_error(
        "car-1",
        "lidar",
        drop_notice(ErrorReason.DROPPED_QUEUE_FULL, [None] * 1024, None),
        "svc",
        5,
        seqs=[None] * 1024,
    ),  # the most frames one notice names
    frame_error("car-1", "lidar", Rejection(ErrorReason.UNKNOWN_CLASS, "", "", 0, 1), "svc", 0),
    missed_notice("car-1", "lidar", "12 frames lost in transport", "svc"),
]


@pytest.mark.parametrize("err", REFUSALS, ids=lambda e: e.reason.value)
def test_a_refusal_is_the_bytes_the_pydantic_model_gave(err: FrameError) -> None:
    # The workers build the light message now; planners must see the same bytes as before.
    model = models.FrameError(**dataclasses.asdict(err))
    assert encode(err) == encode(model)
    assert decode_message(encode(err), FrameError) == err


def test_a_notice_the_decoders_would_refuse_is_still_a_value_error() -> None:
    r = Rejection(ErrorReason.MALFORMED, None, "x", None, None)
    for bad in (
        frame_error("car-1", "lidar", r, instance="no/slash", received_ns=5),
        frame_error("car-1", "lidar", r, instance="svc", received_ns=-1),
        frame_error("car-1", "lidar", r, instance="svc", received_ns=5, seqs=[0] * 1025),
    ):
        with pytest.raises(ValueError, match="FrameError"):
            encode(bad)
