"""Decoding never raises and never hits its catch-all: any bytes give a frame or a typed reason."""

from __future__ import annotations

from typing import Any

import msgpack
import numpy as np
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from simpletrack.core import jit
from simpletrack.wire import (
    BoxArrays,
    DecodedDetections,
    DecodeLimits,
    ErrorReason,
    Rejection,
    decode_detection_frame,
    decode_track_frame,
    decode_vehicle_track_frame,
    encode_detection_frame,
    generate,
)
from simpletrack.wire.convert import detection_extents

CODES = {"Car": 0, "Pedestrian": 1}
LIMITS = DecodeLimits(max_bytes=1 << 16, max_boxes=64)
FUZZ = settings(max_examples=300, deadline=None, suppress_health_check=[HealthCheck.too_slow])


def _valid() -> bytes:
    n = 3
    return encode_detection_frame(
        vehicle="v1",
        sensor="s1",
        seq=1,
        stamp_ns=2,
        frame_id="f",
        pose=np.eye(4),
        boxes=BoxArrays(
            classes=("Car", "Pedestrian"),
            class_index=np.array([0, 1, 0], np.int32),
            center=np.zeros((n, 3), np.float32),
            size=np.ones((n, 3), np.float32),
            yaw=np.zeros(n, np.float32),
            score=np.ones(n, np.float32),
            velocity=np.zeros((n, 2), np.float32),
        ),
    )


VALID = _valid()
VALID_OBJ: dict[str, Any] = msgpack.unpackb(VALID, raw=False)


def check(data: bytes) -> None:
    out = decode_detection_frame(data, LIMITS, CODES)
    assert isinstance(out, DecodedDetections | Rejection)
    if isinstance(out, Rejection):
        assert isinstance(out.reason, ErrorReason)
        assert out.reason is not ErrorReason.INTERNAL_ERROR, out.detail
    assert_same(decode_detection_frame(data, LIMITS, CODES, detection_extents), out)
    tracks = decode_track_frame(data, LIMITS)
    if isinstance(tracks, Rejection):
        assert tracks.reason is not ErrorReason.INTERNAL_ERROR, tracks.detail
    fused = decode_vehicle_track_frame(data, LIMITS)
    if isinstance(fused, Rejection):
        assert fused.reason is not ErrorReason.INTERNAL_ERROR, fused.detail


def assert_same(got: DecodedDetections | Rejection, want: DecodedDetections | Rejection) -> None:
    """The service's decoding (its columns' extents from the compiled reduction) is the
    plain decoder's: the same refusal, or the same frame, columns, extents and codes."""
    if isinstance(want, Rejection):
        assert got == want
        return
    assert isinstance(got, DecodedDetections)
    assert (got.frame, got.extents) == (want.frame, want.extents)
    assert got.boxes.classes == want.boxes.classes
    for name in ("class_index", "center", "size", "yaw", "score", "velocity"):
        g, w = getattr(got.boxes, name), getattr(want.boxes, name)
        assert (g is None and w is None) or (g.tobytes(), g.shape) == (w.tobytes(), w.shape)
    for g, w in ((got.pose, want.pose), (got.extrinsic, want.extrinsic), (got.codes, want.codes)):
        assert (g is None and w is None) or np.array_equal(g, w)


msgpack_values = st.recursive(
    st.none()
    | st.booleans()
    | st.integers(min_value=-(2**63), max_value=2**64 - 1)
    | st.floats(allow_nan=True, allow_infinity=True)
    | st.text(max_size=20)
    | st.binary(max_size=64),
    lambda children: (
        st.lists(children, max_size=5) | st.dictionaries(st.text(max_size=12), children, max_size=5)
    ),
    max_leaves=20,
)


@FUZZ
@given(st.binary(max_size=512))
def test_random_bytes(data: bytes) -> None:
    check(data)


@FUZZ
@given(msgpack_values)
def test_random_msgpack_documents(value: Any) -> None:
    check(msgpack.packb(value, use_bin_type=True))


def _paths(obj: dict[str, Any], prefix: tuple[str, ...] = ()) -> list[tuple[str, ...]]:
    out = []
    for k, v in obj.items():
        out.append((*prefix, k))
        if isinstance(v, dict):
            out += _paths(v, (*prefix, k))
    return out


PATHS = _paths(VALID_OBJ)


def _replaced(payload: bytes, path: tuple[str, ...], value: Any) -> bytes:
    """``payload`` with the field at ``path`` set to ``value`` (removed: ``"__delete__"``)."""
    obj = msgpack.unpackb(payload, raw=False)
    target = obj
    for p in path[:-1]:
        target = target[p]
    if value == "__delete__":
        del target[path[-1]]
    else:
        target[path[-1]] = value
    return bytes(msgpack.packb(obj, use_bin_type=True))


@FUZZ
@given(st.sampled_from(PATHS), msgpack_values | st.just("__delete__"))
def test_one_field_replaced_or_removed(path: tuple[str, ...], value: Any) -> None:
    check(_replaced(VALID, path, value))


VEHICLE = generate._vehicle_tracks()
VEHICLE_PATHS = _paths(msgpack.unpackb(VEHICLE, raw=False))


@FUZZ
@given(st.sampled_from(VEHICLE_PATHS), msgpack_values | st.just("__delete__"))
def test_one_field_of_a_vehicle_frame_replaced_or_removed(
    path: tuple[str, ...], value: Any
) -> None:
    check(_replaced(VEHICLE, path, value))


@FUZZ
@given(st.integers(0, 4), st.integers(0, 4), st.lists(st.integers(-3, 2**62), max_size=24))
def test_vehicle_columns_of_any_width(n: int, sensors: int, stamps: list[int]) -> None:
    """Counts, sensor lists and stamp buffers that agree or not: width and value rules decide."""
    obj = msgpack.unpackb(VEHICLE, raw=False)
    obj["sensors"] = [f"s{i}" for i in range(sensors)] or obj["sensors"][:0]
    obj["sensor_state"] = ["ok"] * sensors
    obj["sensor"] = "s0"
    obj["tracks"]["count"] = n
    obj["tracks"]["sensor_stamp_ns"] = np.array(stamps, np.int64).tobytes()
    check(msgpack.packb(obj, use_bin_type=True))


@FUZZ
@given(st.data())
def test_bytes_flipped_inserted_or_cut(data: st.DataObject) -> None:
    buf = bytearray(VALID)
    for _ in range(data.draw(st.integers(1, 6))):
        op = data.draw(st.sampled_from(["flip", "insert", "cut"]))
        i = data.draw(st.integers(0, max(0, len(buf) - 1)))
        if op == "flip" and buf:
            buf[i] ^= data.draw(st.integers(1, 255))
        elif op == "insert":
            buf[i:i] = data.draw(st.binary(min_size=1, max_size=8))
        elif buf:
            del buf[i : i + data.draw(st.integers(1, 16))]
    check(bytes(buf))


@FUZZ
@given(
    st.integers(0, 8),
    st.lists(st.floats(width=32, allow_nan=True, allow_infinity=True), min_size=24, max_size=24),
    st.lists(st.floats(allow_nan=True, allow_infinity=True), min_size=8, max_size=8),
    st.lists(st.integers(-2, 3), min_size=8, max_size=8),
    st.booleans(),
)
def test_column_contents(
    n: int, floats: list[float], scores: list[float], index: list[int], velocity: bool
) -> None:
    """Well-formed maps with arbitrary column values (NaN, inf, zeros of both signs, sizes
    not positive, indices out of the table, with and without velocity): the finite, size and
    index rules decide, and the decoder given the compiled reduction refuses or accepts
    each frame as the plain one does, with the same extents."""
    f = np.array(floats, np.float32)
    obj = msgpack.unpackb(VALID, raw=False)
    b = obj["boxes"]
    b["count"] = n
    b["class_index"] = np.array(index[:n], np.int32).tobytes()
    b["center"] = f[: 3 * n].tobytes()
    b["size"] = f[-3 * n :].tobytes() if n else b""
    b["yaw"] = f[n : 2 * n].tobytes()
    b["score"] = np.array(scores[:n], np.float64).tobytes()
    if velocity:
        b["velocity"] = f[5 : 5 + 2 * n].tobytes()
    else:
        del b["velocity"]
    data = msgpack.packb(obj, use_bin_type=True)
    calls: list[bool] = []

    def counted(*columns: Any) -> Any:
        found = detection_extents(*columns)
        calls.append(found is not None)
        return found

    check(data)
    want = decode_detection_frame(data, LIMITS, CODES)
    assert_same(decode_detection_frame(data, LIMITS, CODES, counted), want)
    assert calls == ([jit.compiled()] if n else [])  # it ran whatever the values
    if isinstance(want, DecodedDetections):
        assert np.isfinite(want.boxes.center).all() and (want.boxes.size > 0).all()
        assert ((want.boxes.class_index >= 0) & (want.boxes.class_index < 2)).all()
