"""The wire contract: round trips, every validation reason, golden vectors, schema drift."""

from __future__ import annotations

import json
import math
from typing import Any

import msgpack
import numpy as np
import pytest

from simpletrack.wire import (
    BoxArrays,
    DecodedDetections,
    DecodeLimits,
    ErrorReason,
    FrameError,
    Rejection,
    TrackArrays,
    decode_detection_frame,
    decode_message,
    decode_track_frame,
    encode,
    encode_detection_frame,
    encode_track_frame,
    generate,
)

CODES = {"Car": 0, "Pedestrian": 1, "Cyclist": 2}


def boxes(n: int = 3, velocity: bool = False) -> BoxArrays:
    rng = np.random.default_rng(n)
    return BoxArrays(
        classes=("Car", "Pedestrian"),
        class_index=(np.arange(n) % 2).astype(np.int32),
        center=rng.normal(size=(n, 3)).astype(np.float32),
        size=rng.uniform(0.5, 5, size=(n, 3)).astype(np.float32),
        yaw=rng.uniform(-3, 3, size=n).astype(np.float32),
        score=rng.uniform(0, 1, size=n).astype(np.float32),
        velocity=rng.normal(size=(n, 2)).astype(np.float32) if velocity else None,
    )


def payload(**over: Any) -> bytes:
    kw: dict[str, Any] = dict(
        vehicle="v1", sensor="lidar", seq=7, stamp_ns=1_000_000_000, frame_id="lidar", boxes=boxes()
    )
    kw.update(over)
    return encode_detection_frame(**kw)


def mutated(path: str, value: Any, base: bytes | None = None) -> bytes:
    obj = msgpack.unpackb(base or payload(), raw=False)
    target = obj
    *parents, last = path.split(".")
    for p in parents:
        target = target[p]
    if value is DELETE:
        del target[last]
    else:
        target[last] = value
    return msgpack.packb(obj, use_bin_type=True)


DELETE = object()


def test_detection_round_trip_keeps_every_column_bit_exact() -> None:
    b = boxes(5, velocity=True)
    pose = np.eye(4)
    pose[:3, 3] = [100.0, -20.0, 1.5]
    d = decode_detection_frame(payload(boxes=b, pose=pose, key_frame=False), class_codes=CODES)
    assert isinstance(d, DecodedDetections), d
    for name in ("class_index", "center", "size", "yaw", "score", "velocity"):
        np.testing.assert_array_equal(getattr(d.boxes, name), getattr(b, name))
    assert d.boxes.classes == ("Car", "Pedestrian")
    assert d.codes is not None and d.codes.tolist() == [0, 1, 0, 1, 0]
    assert d.pose is not None and np.array_equal(d.pose, pose)
    assert (d.frame.seq, d.frame.stamp_ns, d.frame.key_frame) == (7, 1_000_000_000, False)


def test_extrinsic_makes_version_2_and_round_trips() -> None:
    extrinsic = np.array(_ROT_VALID).reshape(4, 4)
    data = payload(extrinsic=extrinsic, pose=np.eye(4), session_id=3)
    obj = msgpack.unpackb(data, raw=False)
    assert obj["schema_version"] == 2
    assert list(obj)[-4:] == ["boxes", "pose", "session_id", "extrinsic"]
    d = decode_detection_frame(data, class_codes=CODES)
    assert isinstance(d, DecodedDetections), d
    assert d.extrinsic is not None and np.array_equal(d.extrinsic, extrinsic)
    assert d.frame.extrinsic == _ROT_VALID and d.frame.schema_version == 2


def test_without_extrinsic_the_frame_stays_version_1_and_its_bytes() -> None:
    data = payload()
    assert msgpack.unpackb(data, raw=False)["schema_version"] == 1
    assert payload(extrinsic=None) == data
    d = decode_detection_frame(data, class_codes=CODES)
    assert isinstance(d, DecodedDetections) and d.extrinsic is None


def test_version_2_without_extrinsic_is_read() -> None:
    d = decode_detection_frame(mutated("schema_version", 2), class_codes=CODES)
    assert isinstance(d, DecodedDetections), d
    assert d.frame.schema_version == 2 and d.extrinsic is None


def test_empty_frame_is_valid() -> None:
    d = decode_detection_frame(payload(boxes=boxes(0)), class_codes=CODES)
    assert isinstance(d, DecodedDetections) and len(d.boxes) == 0


def test_track_frame_round_trip() -> None:
    n = 4
    t = TrackArrays(
        classes=("Car", "Pedestrian", "Cyclist"),
        id=np.arange(n, dtype=np.int64) + 2**40,
        class_index=np.zeros(n, np.int32),
        center=np.ones((n, 3), np.float32),
        size=np.ones((n, 3), np.float32),
        yaw=np.zeros(n, np.float32),
        score=np.full(n, 0.5, np.float32),
        velocity=np.zeros((n, 3), np.float32),
        state=np.array([0, 1, 2, 1], np.int32),
        hits=np.arange(n, dtype=np.int32),
        age=np.arange(n, dtype=np.int32),
        time_since_update=np.zeros(n, np.int32),
    )
    data = encode_track_frame(
        vehicle="v1",
        sensor="s1",
        seq=3,
        stamp_ns=9,
        frame_id="world",
        pose=None,
        key_frame=True,
        instance="svc",
        received_ns=10,
        published_ns=11,
        tracks=t,
    )
    out = decode_track_frame(data)
    assert not isinstance(out, Rejection), out
    frame, arrays = out
    assert frame.published_ns == 11 and arrays.id.tolist() == t.id.tolist()
    np.testing.assert_array_equal(arrays.state, t.state)


def test_frame_error_round_trip() -> None:
    err = FrameError(
        schema_version=1,
        vehicle="v1",
        sensor="s1",
        seq=None,
        reason=ErrorReason.MALFORMED,
        detail="x",
        instance="svc",
        received_ns=5,
    )
    assert decode_message(encode(err), FrameError) == err


_NAN = np.array([[0, 0, 0], [np.nan, 0, 0], [0, 0, 0]], np.float32).tobytes()
_INF_YAW = np.array([0, np.inf, 0], np.float32).tobytes()
_ZERO_H = np.array([[1, 1, 1], [1, 1, 0], [1, 1, 1]], np.float32).tobytes()
_NEG_W = np.array([[1, -1, 1], [1, 1, 1], [1, 1, 1]], np.float32).tobytes()
_ROT = [0.5, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1]  # scaled, not rigid
_HUGE = np.array([[0, 0, 0], [0, 3.4e38, 0], [0, 0, 0]], np.float32).tobytes()
_LONG = np.array([[1, 1, 1], [101, 1, 1], [1, 1, 1]], np.float32).tobytes()
_SPUN = np.array([0, 0, -2e4], np.float32).tobytes()
_FAST = np.array([[0, 0], [0, 0], [0, 250]], np.float32).tobytes()
_FAR = [1, 0, 0, 2e5, 0, 1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1]  # rigid, 200 km away
_EYE = [float(v) for v in np.eye(4).reshape(16)]
_MIRROR = [1.0, 0, 0, 0, 0, 1, 0, 0, 0, 0, -1, 0, 0, 0, 0, 1]  # orthonormal, a reflection
_ROT_VALID = [0.0, -1.0, 0, 1.5, 1.0, 0.0, 0, 0, 0, 0, 1, 1.8, 0, 0, 0, 1]
V2 = payload(extrinsic=_ROT_VALID)

BAD_INPUTS: list[tuple[str, bytes, ErrorReason, str | None]] = [
    ("not msgpack", b"\xc1\xc1\xc1", ErrorReason.MALFORMED, "payload"),
    ("truncated", payload()[:-4], ErrorReason.MALFORMED, "payload"),
    ("trailing bytes", payload() + b"\x00", ErrorReason.MALFORMED, "payload"),
    ("not a map", msgpack.packb([1, 2, 3]), ErrorReason.MALFORMED, "payload"),
    ("no version", mutated("schema_version", DELETE), ErrorReason.MISSING_FIELD, "schema_version"),
    ("version 3", mutated("schema_version", 3), ErrorReason.WRONG_VERSION, "schema_version"),
    ("version str", mutated("schema_version", "1"), ErrorReason.WRONG_TYPE, "schema_version"),
    ("no seq", mutated("seq", DELETE), ErrorReason.MISSING_FIELD, "seq"),
    ("no boxes.score", mutated("boxes.score", DELETE), ErrorReason.MISSING_FIELD, "boxes.score"),
    ("extra field", mutated("speed", 3.0), ErrorReason.EXTRA_FIELD, "speed"),
    ("extra in boxes", mutated("boxes.colour", b""), ErrorReason.EXTRA_FIELD, "boxes.colour"),
    ("seq as str", mutated("seq", "7"), ErrorReason.WRONG_TYPE, "seq"),
    ("seq as float", mutated("seq", 7.0), ErrorReason.WRONG_TYPE, "seq"),
    ("column as list", mutated("boxes.yaw", [0.0, 0.0, 0.0]), ErrorReason.WRONG_TYPE, "boxes.yaw"),
    ("negative seq", mutated("seq", -1), ErrorReason.INVALID_VALUE, "seq"),
    ("bad vehicle", mutated("vehicle", "a/b"), ErrorReason.INVALID_VALUE, "vehicle"),
    ("pose of 15", mutated("pose", [0.0] * 15), ErrorReason.INVALID_VALUE, "pose"),
    ("pose not rigid", mutated("pose", _ROT), ErrorReason.INVALID_VALUE, "pose"),
    ("pose NaN", mutated("pose", [float("nan")] * 16), ErrorReason.NON_FINITE, "pose"),
    ("short column", mutated("boxes.yaw", b"\0" * 8), ErrorReason.COLUMN_LENGTH, "boxes.yaw"),
    ("count lies", mutated("boxes.count", 4), ErrorReason.COLUMN_LENGTH, "boxes.class_index"),
    ("NaN centre", mutated("boxes.center", _NAN), ErrorReason.NON_FINITE, "boxes.center"),
    ("inf yaw", mutated("boxes.yaw", _INF_YAW), ErrorReason.NON_FINITE, "boxes.yaw"),
    ("zero height", mutated("boxes.size", _ZERO_H), ErrorReason.NON_POSITIVE_SIZE, "boxes.size"),
    ("negative width", mutated("boxes.size", _NEG_W), ErrorReason.NON_POSITIVE_SIZE, "boxes.size"),
    ("centre at 3.4e38", mutated("boxes.center", _HUGE), ErrorReason.INVALID_VALUE, "boxes.center"),
    ("101 m long", mutated("boxes.size", _LONG), ErrorReason.INVALID_VALUE, "boxes.size"),
    ("yaw of -2e4", mutated("boxes.yaw", _SPUN), ErrorReason.INVALID_VALUE, "boxes.yaw"),
    (
        "250 m/s",
        mutated("boxes.velocity", _FAST, payload(boxes=boxes(velocity=True))),
        ErrorReason.INVALID_VALUE,
        "boxes.velocity",
    ),
    ("pose 200 km away", mutated("pose", _FAR), ErrorReason.INVALID_VALUE, "pose"),
    ("v1 with extrinsic", mutated("extrinsic", _EYE), ErrorReason.EXTRA_FIELD, "extrinsic"),
    (
        "extrinsic of 15",
        mutated("extrinsic", [0.0] * 15, V2),
        ErrorReason.INVALID_VALUE,
        "extrinsic",
    ),
    (
        "extrinsic NaN",
        mutated("extrinsic", [math.nan] * 16, V2),
        ErrorReason.NON_FINITE,
        "extrinsic",
    ),
    ("extrinsic scaled", mutated("extrinsic", _ROT, V2), ErrorReason.INVALID_VALUE, "extrinsic"),
    (
        "extrinsic mirrored",
        mutated("extrinsic", _MIRROR, V2),
        ErrorReason.INVALID_VALUE,
        "extrinsic",
    ),
    ("extrinsic far away", mutated("extrinsic", _FAR, V2), ErrorReason.INVALID_VALUE, "extrinsic"),
    (
        "pose before extrinsic",
        mutated("pose", _ROT, payload(pose=np.eye(4), extrinsic=_ROT_VALID)),
        ErrorReason.INVALID_VALUE,
        "pose",
    ),
    (
        "extrinsic before classes",
        mutated("boxes.classes", ["Car", "Tram"], mutated("extrinsic", _ROT, V2)),
        ErrorReason.INVALID_VALUE,
        "extrinsic",
    ),
    (
        "index past table",
        mutated("boxes.class_index", np.array([0, 1, 2], np.int32).tobytes()),
        ErrorReason.INVALID_VALUE,
        "boxes.class_index",
    ),
    (
        "unknown class",
        mutated("boxes.classes", ["Car", "Tram"]),
        ErrorReason.UNKNOWN_CLASS,
        "boxes.classes.1",
    ),
    ("too many boxes", payload(boxes=boxes(11)), ErrorReason.TOO_LARGE, "boxes.count"),
]


@pytest.mark.parametrize(
    ("payload_bytes", "reason", "field"),
    [pytest.param(p, r, f, id=name) for name, p, r, f in BAD_INPUTS],
)
def test_every_bad_input_is_a_typed_rejection_naming_the_field(
    payload_bytes: bytes, reason: ErrorReason, field: str | None
) -> None:
    out = decode_detection_frame(payload_bytes, DecodeLimits(max_boxes=10), class_codes=CODES)
    assert isinstance(out, Rejection), out
    assert (out.reason, out.field) == (reason, field), out.detail


def test_values_exactly_at_their_bounds_are_accepted() -> None:
    n = 2
    edge = BoxArrays(
        classes=("Car",),
        class_index=np.zeros(n, np.int32),
        center=np.array([[1e5, -1e5, 1e5], [0, 0, 0]], np.float32),
        size=np.array([[100, 100, 100], [1, 1, 1]], np.float32),
        yaw=np.array([1e4, -1e4], np.float32),
        score=np.array([1e300, -1e300]),
        velocity=np.array([[200, -200], [0, 0]], np.float32),
    )
    pose = np.eye(4)
    pose[:3, 3] = [1e5, -1e5, 1e5]
    out = decode_detection_frame(payload(boxes=edge, pose=pose), class_codes=CODES)
    assert isinstance(out, DecodedDetections), out


def test_oversized_payload_is_rejected_before_parsing() -> None:
    out = decode_detection_frame(payload(boxes=boxes(200)), DecodeLimits(max_bytes=2048))
    assert isinstance(out, Rejection)
    assert (out.reason, out.field) == (ErrorReason.TOO_LARGE, "payload")


def test_rejection_keeps_seq_and_stamp_when_readable() -> None:
    out = decode_detection_frame(mutated("boxes.yaw", b"\0"), class_codes=CODES)
    assert isinstance(out, Rejection)
    assert (out.seq, out.stamp_ns) == (7, 1_000_000_000)


def test_unused_unknown_names_in_the_class_table_are_fine() -> None:
    b = boxes(2)
    b = BoxArrays(**{**{k: getattr(b, k) for k in b.__slots__}, "classes": ("Car", "Tram")})
    b = BoxArrays(
        **{**{k: getattr(b, k) for k in b.__slots__}, "class_index": np.zeros(2, np.int32)}
    )
    out = decode_detection_frame(payload(boxes=b), class_codes=CODES)
    assert isinstance(out, DecodedDetections)


# --- golden vectors and generated files --------------------------------------------------


def test_generated_files_have_not_drifted() -> None:
    assert generate.drift() == [], "run: python -m simpletrack.wire.generate"


VECTORS = sorted(generate.VECTOR_DIR.glob("*.msgpack"))


@pytest.mark.parametrize("path", VECTORS, ids=[p.stem for p in VECTORS])
def test_golden_vector_decodes_to_its_json(path: Any) -> None:
    expected = json.loads(path.with_suffix(".json").read_text())
    data = path.read_bytes()
    got = json.loads(json.dumps(generate.decoded_json(expected["message"], data)))
    assert got == expected
    if expected["valid"] and expected["message"] == "DetectionFrame":
        d = decode_detection_frame(data)
        assert isinstance(d, DecodedDetections)
        again = encode_detection_frame(
            vehicle=d.frame.vehicle,
            sensor=d.frame.sensor,
            seq=d.frame.seq,
            stamp_ns=d.frame.stamp_ns,
            frame_id=d.frame.frame_id,
            boxes=d.boxes,
            pose=d.pose,
            key_frame=d.frame.key_frame,
            session_id=d.frame.session_id,
            extrinsic=d.extrinsic,
        )
        assert again == data, "the encoder is canonical: same message, same bytes"


def test_vectors_cover_every_payload_reason_a_decoder_can_give() -> None:
    reasons = {
        json.loads(p.read_text()).get("reason") for p in generate.VECTOR_DIR.glob("invalid_*.json")
    }
    assert {
        "malformed",
        "wrong_version",
        "missing_field",
        "extra_field",
        "wrong_type",
        "invalid_value",
        "column_length",
        "non_finite",
        "non_positive_size",
    } <= reasons


def test_only_invalid_vectors_are_invalid() -> None:
    for p in generate.VECTOR_DIR.glob("*.json"):
        assert json.loads(p.read_text())["valid"] is not p.name.startswith("invalid_"), p.name
