"""The cross-language fixture frame (fixture_boxes.json, the same boxes for the Rust, C++ and
ROS 2 clients) as the Python reference encoder writes it, and the comparison every client's
bytes go through: decoded in Python, they must give the reference's fields and arrays."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np

from simpletrack.wire import BoxArrays, Rejection
from simpletrack.wire.codec import decode_detection_frame, encode_detection_frame

FIXTURE = Path(__file__).with_name("fixture_boxes.json")


def fixture() -> dict[str, Any]:
    data: dict[str, Any] = json.loads(FIXTURE.read_text())
    return data


def reference_payload() -> bytes:
    f = fixture()
    boxes = BoxArrays(
        classes=tuple(f["classes"]),
        class_index=np.array(f["class_index"], np.int32),
        center=np.array(f["center"], np.float32),
        size=np.array(f["size"], np.float32),
        yaw=np.array(f["yaw"], np.float32),
        score=np.array(f["score"], np.float64),
        velocity=np.array(f["velocity"], np.float32),
    )
    return encode_detection_frame(
        vehicle=f["vehicle"],
        sensor=f["sensor"],
        seq=f["seq"],
        stamp_ns=f["stamp_ns"],
        frame_id=f["frame_id"],
        boxes=boxes,
    )


def assert_same_frame(payload: bytes, who: str) -> None:
    """``payload`` decodes to the reference frame: header and every column, exactly."""
    got = decode_detection_frame(payload)
    want = decode_detection_frame(reference_payload())
    assert not isinstance(got, Rejection), f"{who}'s fixture frame refused: {got}"
    assert not isinstance(want, Rejection), want
    for name in ("vehicle", "sensor", "seq", "stamp_ns", "frame_id", "pose", "key_frame"):
        assert getattr(got.frame, name) == getattr(want.frame, name), f"{who}: {name}"
    assert got.boxes.classes == want.boxes.classes, who
    for name in ("class_index", "center", "size", "yaw", "score", "velocity"):
        g, w = getattr(got.boxes, name), getattr(want.boxes, name)
        assert g is not None and w is not None, f"{who}: {name} missing"
        assert g.dtype == w.dtype, f"{who}: {name} is {g.dtype}, not {w.dtype}"
        np.testing.assert_array_equal(g, w, err_msg=f"{who}: {name}")
