"""The pydantic-free validator of ``simpletrack.wire.messages`` against the pydantic models it
replaced on the decode path: for valid and mutated maps of every message, the same verdict,
the same (reason, field, message) for the first error, and the same values when accepted."""

from __future__ import annotations

import copy
import dataclasses
from typing import Any

import msgpack
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from pydantic import BaseModel, ValidationError

from simpletrack.wire import ErrorReason, codec, generate, messages, models
from simpletrack.wire.fields import Invalid
from simpletrack.wire.messages import SPECS, to_map
from tests.wire.test_fuzz import msgpack_values

AGREE = settings(max_examples=250, deadline=None, suppress_health_check=[HealthCheck.too_slow])


def _pydantic_verdict(model: type[BaseModel], obj: Any) -> tuple[Any, ...]:
    """What the codec reported before the validator: the first pydantic error, mapped."""
    try:
        return ("ok", repr(model.model_validate(obj).model_dump(mode="python")))
    except ValidationError as err:
        first = err.errors(include_url=False)[0]
        kind = first["type"]
        if kind == "missing":
            reason = ErrorReason.MISSING_FIELD
        elif kind == "extra_forbidden":
            reason = ErrorReason.EXTRA_FIELD
        elif kind.endswith("_type") or kind in {"model_attributes_type", "literal_error"}:
            reason = ErrorReason.WRONG_TYPE
        else:
            reason = ErrorReason.INVALID_VALUE
        field = ".".join(str(p) for p in first["loc"]) or None
        return (reason, field, str(first["msg"]))


def _light_verdict(name: str, obj: Any) -> tuple[Any, ...]:
    try:
        return ("ok", repr(to_map(SPECS[name](obj))))
    except Invalid as e:
        return (e.reason, e.field, e.detail)


def _unpacked(payload: bytes) -> dict[str, Any]:
    obj: dict[str, Any] = msgpack.unpackb(payload, raw=False)
    return obj


_STATUS = {
    "vehicle": "truck-07",
    "sensor": "lidar_top",
    "last_seq": 41,
    "last_stamp_ns": None,
    "frames": 12,
    "active_tracks": 3,
    "idle_s": 0.25,
}
_FUSED = {
    "sensor": "radar_rear",
    "state": "clock",
    "last_seq": 7,
    "last_stamp_ns": 1_700_000_000_000_000_000,
    "frames": 7,
    "idle_s": 0.5,
    "latency_s": None,
    "clock_offset_s": 2.25,
    "offset_m": [0.5, -0.25],
    "flagged_frames": 3,
    "detail": "stamps 2.3 s ahead",
}
_VEHICLE = {
    "vehicle": "truck-07",
    "seq": 1042,
    "last_stamp_ns": None,
    "active_tracks": 4,
    "frames": 2000,
    "late_frames": 2,
    "reprocessed_frames": 15,
    "sensors": [_FUSED, {**_FUSED, "sensor": "lidar_top", "state": "ok", "offset_m": None}],
}
_SERVICE_STATUS = {
    "schema_version": 1,
    "instance": "simpletrack-a",
    "version": "0.1.0",
    "preset": "kitti",
    "classes": ["Car", "Pedestrian", "Cyclist"],
    "config_digest": "ab" * 32,
    "started_ns": 1_700_000_000_000_000_000,
    "ready": True,
    "queue_depth": 0,
    "sensors": [_STATUS, {**_STATUS, "sensor": "radar", "idle_s": 3}],
}
BASES: dict[str, dict[str, Any]] = {
    "DetectionFrame": _unpacked(generate.VECTORS["detection_extrinsic"][1]()),
    "DetectionFrameV1": _unpacked(generate.VECTORS["detection_full"][1]()),
    "TrackFrame": _unpacked(generate._tracks(3, epoch=3)),
    "TrackFrameV2": _unpacked(generate._tracks(2)),
    "TrackFrameV1": _unpacked(generate._tracks(1)),
    "VehicleTrackFrame": _unpacked(generate._vehicle_tracks(epoch=2**63 - 1)),
    "VehicleTrackFrameV1": _unpacked(generate._vehicle_tracks()),
    "FrameError": _unpacked(generate._error()),
    "ServiceStatusV1": _SERVICE_STATUS,
    "ServiceStatus": {**_SERVICE_STATUS, "schema_version": 2, "vehicles": [_VEHICLE]},
    "SensorSnapshot": {
        "schema_version": 1,
        "vehicle": "truck-07",
        "sensor": "lidar_top",
        "last_seq": 41,
        "stamp_origin_ns": 5,
        "id_next": 9,
        "config_digest": "ab" * 32,
        "tracker": b"\x00\x01",
        "written_ns": 7,
    },
}
MODELS: dict[str, type[BaseModel]] = {
    "DetectionFrame": models.DetectionFrame,
    "DetectionFrameV1": models.DetectionFrameV1,
    "TrackFrame": models.TrackFrame,
    "TrackFrameV2": models.TrackFrameV2,
    "TrackFrameV1": models.TrackFrameV1,
    "VehicleTrackFrame": models.VehicleTrackFrame,
    "VehicleTrackFrameV1": models.VehicleTrackFrameV1,
    "FrameError": models.FrameError,
    "ServiceStatus": models.ServiceStatus,
    "ServiceStatusV1": models.ServiceStatusV1,
    "SensorSnapshot": models.SensorSnapshot,
}


def _paths(obj: Any, prefix: tuple[Any, ...] = ()) -> list[tuple[Any, ...]]:
    """Every key and list index of a map, nested ones included."""
    items = obj.items() if isinstance(obj, dict) else enumerate(obj)
    out = []
    for k, v in items:
        out.append((*prefix, k))
        if isinstance(v, dict | list) and not isinstance(v, bytes):
            out += _paths(v, (*prefix, k))
    return out


# Values at the edges of the rules: bounds, patterns, lengths, near-miss types.
EDGE_VALUES: list[Any] = [
    -1,
    0,
    1,
    True,
    False,
    1.0,
    0.5,
    float("nan"),
    2**31 - 1,
    2**31,
    2**63 - 1,
    2**63,
    -(2**63),
    "",
    "a",
    "v1",
    "v1\n",
    "a/b",
    ".hidden",
    "a" * 64,
    "a" * 65,
    "a" * 129,
    "a" * 257,
    "a" * 1025,
    "é",
    "malformed",
    "unknown_class",
    b"",
    b"malformed",
    b"\xff",
    None,
    [],
    {},
    [1.0] * 15,
    [1.0] * 16,
    [1] * 16,
    [1.0] * 17,
    [1.0] * 15 + ["x"],
    ["x"] + [1.0] * 16,
    ["Car"],
    ["Car", ""],
    ["a" * 65],
    ["a"] * 1025,
    [""] + ["a"] * 1024,
    [_STATUS],
    [{**_STATUS, "frames": -1}],
    [3],
    [True] * 16,
    "@vehicle",
    "@vehicle2",
    "ok",
    "clock",
    b"ok",
    ["ok"],
    ["ok", "silent"],
    ["ok", "tired"],
    ["lidar_top", "lidar_top"],
    ["a"] * 64,
    ["a"] * 65,
    [0.5, 1.5],
    [0.5, None],
    [_VEHICLE],
    [{**_VEHICLE, "late_frames": -1}],
    [_FUSED] * 65,
    [{**_FUSED, "state": "fine"}],
]
EDGES = st.sampled_from(EDGE_VALUES)
VALUES = EDGES | msgpack_values | st.just("__delete__")
KEYS = st.sampled_from(["speed", "b", "count", "Seq", b"seq", b"x"]) | st.text(max_size=6)


def _mutate(obj: dict[str, Any], path: tuple[Any, ...], value: Any) -> None:
    target: Any = obj
    for p in path[:-1]:
        target = target[p]
    if value == "__delete__":
        if isinstance(target, dict):
            del target[path[-1]]
        else:
            target.pop(path[-1])
    else:
        target[path[-1]] = copy.deepcopy(value)  # EDGES hands out shared objects


def _assert_agree(name: str, obj: Any) -> None:
    assert _light_verdict(name, obj) == _pydantic_verdict(MODELS[name], obj)


@pytest.mark.parametrize("name", sorted(BASES))
def test_valid_messages_are_accepted_with_the_same_values(name: str) -> None:
    assert _light_verdict(name, BASES[name])[0] == "ok"
    _assert_agree(name, BASES[name])


@pytest.mark.parametrize("name", sorted(BASES))
def test_every_field_absent_gives_the_same_verdict(name: str) -> None:
    for path in _paths(BASES[name]):
        obj = copy.deepcopy(BASES[name])
        _mutate(obj, path, "__delete__")
        _assert_agree(name, obj)


@pytest.mark.parametrize("name", sorted(BASES))
def test_each_edge_value_in_each_place_gives_the_same_verdict(name: str) -> None:
    for path in _paths(BASES[name]):
        for value in EDGE_VALUES:
            obj = copy.deepcopy(BASES[name])
            _mutate(obj, path, value)
            _assert_agree(name, obj)


@pytest.mark.parametrize("name", sorted(BASES))
@AGREE
@given(data=st.data())
def test_mutated_maps_give_the_same_first_error(name: str, data: st.DataObject) -> None:
    obj = copy.deepcopy(BASES[name])
    for _ in range(data.draw(st.integers(1, 3))):
        paths = _paths(obj)
        if not paths or data.draw(st.integers(0, 4)) == 0:
            # An unknown key at the top or in a nested map.
            maps = [()] + [p for p in paths if isinstance(_at(obj, p), dict)]
            where = data.draw(st.sampled_from(maps))
            _at(obj, where)[data.draw(KEYS)] = data.draw(msgpack_values)
        else:
            _mutate(obj, data.draw(st.sampled_from(paths)), data.draw(VALUES))
    _assert_agree(name, obj)


@AGREE
@given(value=msgpack_values)
def test_any_document_gives_the_same_verdict(value: Any) -> None:
    for name in MODELS:
        _assert_agree(name, value)


def _at(obj: Any, path: tuple[Any, ...]) -> Any:
    for p in path:
        obj = obj[p]
    return obj


def _encoded_by_the_table(message: Any) -> bytes | str:
    """What ``encode`` gave a light message before its FrameError shortcut: the field
    table's verdict on ``to_map``, then the map packed (or the error's field)."""
    obj = to_map(message)
    try:
        SPECS[type(message).__name__](obj)
    except Invalid as e:
        return f"invalid {e.field}"
    return codec.pack(obj)


def _encoded(message: Any) -> bytes | str:
    try:
        return codec.encode(message)
    except ValueError as e:
        return f"invalid {str(e).split(':')[0].removeprefix('FrameError.')}"


@pytest.mark.parametrize("field", [f.name for f in dataclasses.fields(messages.FrameError)])
def test_a_frame_error_is_encoded_as_its_field_table_says(field: str) -> None:
    # encode's shortcut for FrameError (a worker refuses garbage by the thousand) takes only
    # what the table accepts, and gives the same bytes; anything else goes the table's way.
    base = dict(
        schema_version=1,
        vehicle="truck-07",
        sensor="lidar_top",
        seq=42,
        stamp_ns=None,
        reason=ErrorReason.MALFORMED,
        field="boxes",
        detail="x",
        instance="svc",
        received_ns=5,
        seqs=[1, None],
    )
    for value in [*EDGE_VALUES, ErrorReason.LATE, [None] * 1024, [0] * 1025, [2**63]]:
        err = messages.FrameError(**{**base, field: value})
        assert _encoded(err) == _encoded_by_the_table(err), (field, value)
