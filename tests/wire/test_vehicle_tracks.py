"""VehicleTrackFrame: a vehicle's fused tracks round trip, every rule of its own (the
per-sensor column's width, existence in [0, 1], stamps at least -1, one state per unique
sensor) refuses what breaks it with its reason and field, and its key is one that sensor
wildcards never match."""

from __future__ import annotations

from dataclasses import replace
from typing import Any

import msgpack
import numpy as np
import pytest
import zenoh

from simpletrack.wire import (
    Rejection,
    SensorCondition,
    TrackArrays,
    VehicleTrackFrame,
    decode_track_frame,
    decode_vehicle_track_frame,
    encode_vehicle_track_frame,
    generate,
)
from simpletrack.wire.fields import Invalid, string
from simpletrack.wire.header import restamp_tracks
from simpletrack.wire.keys import VEHICLE_STREAM, Keys
from simpletrack.wire.messages import NAME_PATTERN
from simpletrack.wire.track_ids import global_id, global_ids
from tests.wire.test_contract import DELETE, mutated

SENSORS = ["lidar_top", "radar_rear", "camera_front"]
STATES = [SensorCondition.OK, SensorCondition.CLOCK, SensorCondition.UNSEEN]


def _arrays(n: int = 3, s: int = 3) -> TrackArrays:
    rng = np.random.default_rng(2)
    stamps = rng.integers(10**18, 2 * 10**18, size=(n, s))
    stamps[:, -1] = -1  # the unseen camera updated nothing
    return TrackArrays(
        classes=("Car", "Pedestrian"),
        id=np.arange(n, dtype=np.int64) + 2**40,
        class_index=np.zeros(n, np.int32),
        center=rng.normal(size=(n, 3)).astype(np.float32),
        size=np.ones((n, 3), np.float32),
        yaw=np.zeros(n, np.float32),
        score=np.full(n, 0.5),
        velocity=np.zeros((n, 3), np.float32),
        state=np.ones(n, np.int32),
        hits=np.arange(n, dtype=np.int32),
        age=np.arange(n, dtype=np.int32),
        time_since_update=np.zeros(n, np.int32),
        covariance=np.ones((n, 21), np.float32),
        age_s=np.linspace(0, 3, n),
        time_since_update_s=np.zeros(n),
        existence=np.linspace(0, 1, n),
        sensor_stamp_ns=stamps.astype(np.int64),
    )


def _encode(tracks: TrackArrays, **over: Any) -> bytes:
    kw: dict[str, Any] = dict(
        vehicle="veh01",
        seq=9,
        stamp_ns=5,
        sensor="radar_rear",
        sensor_seq=3,
        frame_id="base_link",
        pose=None,
        instance="svc",
        received_ns=6,
        published_ns=7,
        sensors=SENSORS,
        sensor_state=STATES,
        tracks=tracks,
    )
    kw.update(over)
    return encode_vehicle_track_frame(**kw)


def _decode(payload: bytes) -> tuple[VehicleTrackFrame, TrackArrays]:
    out = decode_vehicle_track_frame(payload)
    assert not isinstance(out, Rejection), out
    return out


def test_round_trip_keeps_every_column_and_the_sensors() -> None:
    t = _arrays()
    frame, got = _decode(_encode(t, pose=list(np.eye(4).reshape(16))))
    assert (frame.schema_version, frame.vehicle, frame.seq, frame.stamp_ns) == (1, "veh01", 9, 5)
    assert (frame.sensor, frame.sensor_seq, frame.frame_id) == ("radar_rear", 3, "base_link")
    assert frame.sensors == SENSORS and frame.sensor_state == STATES
    assert frame.pose_matrix() is not None
    for name in TrackArrays.__slots__:
        if name != "classes":
            np.testing.assert_array_equal(getattr(got, name), getattr(t, name), err_msg=name)
    assert got.sensor_stamp_ns is not None and got.sensor_stamp_ns.shape == (3, 3)


def test_an_empty_frame_and_one_without_covariance() -> None:
    t = _arrays(0)
    _, got = _decode(_encode(t))
    assert len(got) == 0 and got.sensor_stamp_ns is not None
    assert got.sensor_stamp_ns.shape == (0, 3)
    payload = _encode(replace(_arrays(), covariance=None))
    assert "covariance" not in msgpack.unpackb(payload, raw=False)["tracks"]
    assert _decode(payload)[1].covariance is None


def test_encoder_writes_the_documented_key_order() -> None:
    obj = msgpack.unpackb(_encode(_arrays()), raw=False)
    assert list(obj) == [
        "schema_version",
        "vehicle",
        "seq",
        "stamp_ns",
        "sensor",
        "sensor_seq",
        "frame_id",
        "pose",
        "instance",
        "received_ns",
        "published_ns",
        "sensors",
        "sensor_state",
        "tracks",
    ]
    assert list(obj["tracks"])[-5:] == [
        "covariance",
        "age_s",
        "time_since_update_s",
        "existence",
        "sensor_stamp_ns",
    ]
    assert obj["sensor_state"] == ["ok", "clock", "unseen"]


_STAMPS = _arrays().sensor_stamp_ns
assert _STAMPS is not None


@pytest.mark.parametrize(
    ("path", "value", "reason", "field"),
    [
        ("schema_version", 3, "wrong_version", "schema_version"),
        ("tracks.sensor_stamp_ns", _STAMPS[:, :2].tobytes(), "column_length", None),
        ("sensors", SENSORS[:2], "invalid_value", "sensor_state"),
        ("sensors", [*SENSORS, "radar_front"], "invalid_value", "sensor_state"),
        ("tracks.existence", np.array([0.5, 1.5, 1.0]).tobytes(), "invalid_value", None),
        ("tracks.existence", np.array([0.5, -0.1, 1.0]).tobytes(), "invalid_value", None),
        ("tracks.existence", np.array([0.5, np.nan, 1.0]).tobytes(), "non_finite", None),
        ("tracks.existence", DELETE, "missing_field", None),
        ("tracks.sensor_stamp_ns", DELETE, "missing_field", None),
        ("tracks.sensor_stamp_ns", (_STAMPS - 2**62).tobytes(), "invalid_value", None),
        ("tracks.age_s", None, "wrong_type", None),
        ("sensors", ["lidar_top", "radar_rear", "lidar_top"], "invalid_value", "sensors"),
        ("sensors", [], "invalid_value", "sensors"),
        ("sensors", ["s"] * 65, "invalid_value", "sensors"),
        ("sensors", ["lidar_top", "@vehicle", "x"], "invalid_value", "sensors.1"),
        ("sensor_state", ["ok", "clock"], "invalid_value", "sensor_state"),
        ("sensor_state", ["ok", "clock", "asleep"], "invalid_value", "sensor_state.2"),
        ("sensor", "radar_front", "invalid_value", "sensor"),
        ("sensor_seq", -1, "invalid_value", "sensor_seq"),
        ("key_frame", True, "extra_field", "key_frame"),
    ],
)
def test_refusals_name_the_reason_and_field(
    path: str, value: Any, reason: str, field: str | None
) -> None:
    out = decode_vehicle_track_frame(mutated(path, value, _encode(_arrays())))
    assert isinstance(out, Rejection), out
    assert (out.reason.value, out.field) == (reason, field or path), out.detail
    assert (out.seq, out.stamp_ns) == (9, 5)


def test_a_frame_of_one_kind_is_no_frame_of_the_other() -> None:
    vehicle = _encode(_arrays())
    assert isinstance(decode_track_frame(vehicle), Rejection)
    sensor = (generate.VECTOR_DIR / "tracks_v2.msgpack").read_bytes()
    assert isinstance(decode_vehicle_track_frame(sensor), Rejection)


def test_encoder_refuses_what_no_reader_could_take() -> None:
    with pytest.raises(ValueError, match="needs existence"):
        _encode(replace(_arrays(), existence=None))
    with pytest.raises(ValueError, match=r"shape \(N, 3\)"):
        _encode(replace(_arrays(), sensor_stamp_ns=_STAMPS[:, :2]))
    with pytest.raises(ValueError, match="sensor_state"):
        _encode(_arrays(), sensor_state=STATES[:2])
    with pytest.raises(ValueError, match="sensors"):
        _encode(_arrays(), sensors=["a", "b", "a"])
    with pytest.raises(ValueError, match="not one of sensors"):
        _encode(_arrays(), sensor="radar_front")
    with pytest.raises(ValueError, match="asleep"):
        _encode(_arrays(), sensor_state=["ok", "ok", "asleep"])


def test_the_basic_vector_has_a_track_one_sensor_alone_updated() -> None:
    payload = (generate.VECTOR_DIR / "vehicle_tracks_basic.msgpack").read_bytes()
    frame, tracks = _decode(payload)
    assert tracks.sensor_stamp_ns is not None and len(frame.sensors) == 2
    assert tracks.sensor_stamp_ns.tolist()[1] == [frame.stamp_ns, -1]


def test_the_vehicle_key_is_out_of_reach_of_sensor_wildcards() -> None:
    keys = Keys("fleet")
    key = keys.vehicle_tracks("veh01")
    assert key == "fleet/veh01/@vehicle/tracks"
    assert keys.all_vehicle_tracks == "fleet/*/@vehicle/tracks"
    assert keys.sensor_of(key) == ("veh01", VEHICLE_STREAM)
    k = zenoh.KeyExpr(key)
    assert zenoh.KeyExpr(keys.all_vehicle_tracks).intersects(k)
    for sensor_wide in (keys.all_tracks, keys.tracks("veh01", "*"), "fleet/**"):
        assert not zenoh.KeyExpr(sensor_wide).intersects(k), sensor_wide
    with pytest.raises(Invalid):
        string(pattern=NAME_PATTERN)(VEHICLE_STREAM)  # no sensor can be named so


def test_a_fused_tracks_global_id_names_the_vehicle_stream() -> None:
    assert global_id("veh01", VEHICLE_STREAM, 12) == "veh01/@vehicle/12"
    assert global_ids("veh01", VEHICLE_STREAM, np.array([3, 9])) == [
        "veh01/@vehicle/3",
        "veh01/@vehicle/9",
    ]


def test_a_republished_frame_is_the_same_but_for_who_published_it_and_when() -> None:
    # A failover's new owner publishes the dead holder's last message again as its own.
    tracks = _arrays()
    old = _encode(tracks, epoch=(3 << 16) | 7)
    again = restamp_tracks(old, "svc-b", (4 << 16) | 9, 99)
    assert again is not None
    (f0, t0), (f1, t1) = _decode(old), _decode(again)
    assert (f1.instance, f1.epoch, f1.published_ns) == ("svc-b", (4 << 16) | 9, 99)
    assert replace(f1, instance=f0.instance, epoch=f0.epoch, published_ns=7) == f0
    assert all(np.array_equal(getattr(t0, c), getattr(t1, c)) for c in ("id", "center"))
    assert restamp_tracks(b"\xc1garbage", "svc-b", 1, 99) is None
