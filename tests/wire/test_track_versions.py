"""TrackFrame versions 1 and 2: what each carries, that a reader of both decodes either, and
that a version-1 reader (the field table of version 1) refuses version 2 as schemas/README.md
says, rather than dropping the new columns silently."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path
from typing import Any

import msgpack
import numpy as np
import pytest

from simpletrack.wire import (
    Rejection,
    TrackArrays,
    decode_track_frame,
    encode_track_frame,
    generate,
)
from simpletrack.wire.columns import covariance_from_upper, covariance_to_upper
from simpletrack.wire.fields import Invalid
from simpletrack.wire.header import restamp_tracks
from simpletrack.wire.messages import TRACK_FRAME_V1
from simpletrack.wire.track_ids import global_id, global_ids

VECTORS = Path(generate.__file__).resolve().parents[2] / "vectors"


def _arrays(n: int = 3) -> TrackArrays:
    rng = np.random.default_rng(1)
    a = rng.normal(size=(n, 6, 6))
    cov = a @ a.transpose(0, 2, 1)  # symmetric positive definite, like the filter's
    return TrackArrays(
        classes=("Car", "Pedestrian"),
        id=np.arange(n, dtype=np.int64) + 2**40,
        class_index=np.zeros(n, np.int32),
        center=np.ones((n, 3), np.float32),
        size=np.ones((n, 3), np.float32),
        yaw=np.zeros(n, np.float32),
        score=np.full(n, 0.5),
        velocity=np.zeros((n, 3), np.float32),
        state=np.ones(n, np.int32),
        hits=np.arange(n, dtype=np.int32),
        age=np.arange(n, dtype=np.int32),
        time_since_update=np.zeros(n, np.int32),
        covariance=covariance_to_upper(cov),
        age_s=np.array([0.0, 0.1, 12.3456789])[:n],
        time_since_update_s=np.array([0.0, 0.05, 0.3])[:n],
    )


def _encode(tracks: TrackArrays, version: int | None) -> bytes:
    return encode_track_frame(
        vehicle="truck-07",
        sensor="lidar_top",
        seq=1,
        stamp_ns=5,
        frame_id="world",
        pose=None,
        key_frame=True,
        instance="svc",
        received_ns=6,
        published_ns=7,
        tracks=tracks,
        schema_version=version,
    )


def _decode(payload: bytes) -> tuple[Any, TrackArrays]:
    out = decode_track_frame(payload)
    assert not isinstance(out, Rejection), out
    return out


def test_version_2_round_trip_keeps_the_new_columns() -> None:
    t = _arrays()
    frame, got = _decode(_encode(t, 2))
    assert frame.schema_version == 2
    assert got.covariance is not None and got.age_s is not None
    np.testing.assert_array_equal(got.covariance, t.covariance)  # type: ignore[arg-type]
    np.testing.assert_array_equal(got.age_s, t.age_s)  # type: ignore[arg-type]
    np.testing.assert_array_equal(got.time_since_update_s, t.time_since_update_s)  # type: ignore[arg-type]
    full = got.covariance_matrices()
    assert full is not None and full.shape == (3, 6, 6)
    np.testing.assert_array_equal(full, full.transpose(0, 2, 1))
    assert full[2, 4, 1] == np.float32(t.covariance[2, 5 + 4])  # type: ignore[index]


def test_version_2_without_covariance_leaves_the_key_out() -> None:
    t = replace(_arrays(), covariance=None)
    payload = _encode(t, 2)
    assert "covariance" not in msgpack.unpackb(payload, raw=False)["tracks"]
    _, got = _decode(payload)
    assert got.covariance is None and got.covariance_matrices() is None
    assert got.age_s is not None


def test_version_1_is_the_old_layout_and_decodes_without_the_new_columns() -> None:
    payload = _encode(_arrays(), 1)
    tracks = msgpack.unpackb(payload, raw=False)["tracks"]
    assert not {"covariance", "age_s", "time_since_update_s"} & set(tracks)
    frame, got = _decode(payload)
    assert frame.schema_version == 1
    assert got.covariance is None and got.age_s is None and got.time_since_update_s is None
    assert got.id.tolist() == _arrays().id.tolist()


def test_the_v1_golden_vector_is_what_version_1_encodes() -> None:
    # tracks_basic.msgpack predates version 2: old readers were tested against these bytes.
    assert (VECTORS / "tracks_basic.msgpack").read_bytes() == generate._tracks(1)


def test_a_version_1_reader_refuses_version_2() -> None:
    obj = msgpack.unpackb(_encode(_arrays(), 2), raw=False)
    with pytest.raises(Invalid) as e:
        TRACK_FRAME_V1(obj)
    assert e.value.field == "schema_version"
    obj["schema_version"] = 1  # version 2's columns under the old number: still refused
    with pytest.raises(Invalid) as e:
        TRACK_FRAME_V1(obj)
    assert (e.value.reason, e.value.field) == ("extra_field", "tracks.covariance")


@pytest.mark.parametrize(
    ("path", "value", "reason", "field"),
    [
        ("schema_version", 4, "wrong_version", "schema_version"),
        ("schema_version", 0, "wrong_version", "schema_version"),
        ("tracks.age_s", None, "wrong_type", "tracks.age_s"),
        ("tracks.covariance", b"\0" * 8, "column_length", "tracks.covariance"),
        ("tracks.time_since_update_s", b"\0" * 8, "column_length", "tracks.time_since_update_s"),
    ],
)
def test_version_2_refusals_name_the_field(path: str, value: Any, reason: str, field: str) -> None:
    obj = msgpack.unpackb(_encode(_arrays(), 2), raw=False)
    *parents, last = path.split(".")
    target = obj
    for p in parents:
        target = target[p]
    target[last] = value
    out = decode_track_frame(msgpack.packb(obj, use_bin_type=True))
    assert isinstance(out, Rejection)
    assert (out.reason.value, out.field) == (reason, field)


def test_non_finite_covariance_is_refused() -> None:
    t = _arrays()
    assert t.covariance is not None
    bad = t.covariance.copy()
    bad[1, 3] = np.nan
    out = decode_track_frame(_encode(replace(t, covariance=bad), 2))
    assert isinstance(out, Rejection) and (out.reason.value, out.field) == (
        "non_finite",
        "tracks.covariance",
    )


def test_encoder_refuses_what_no_reader_could_take() -> None:
    with pytest.raises(ValueError, match="needs age_s"):
        _encode(replace(_arrays(), age_s=None), 2)
    with pytest.raises(ValueError, match="schema_version 4"):
        _encode(_arrays(), 4)
    # Left to choose, the encoder sends version 2 when the ages are there, else version 1.
    assert _decode(_encode(_arrays(), None))[0].schema_version == 2
    bare = replace(_arrays(), covariance=None, age_s=None, time_since_update_s=None)
    assert _decode(_encode(bare, None))[0].schema_version == 1


def test_upper_triangle_round_trips_a_symmetric_matrix() -> None:
    m = np.arange(36, dtype=np.float64).reshape(1, 6, 6)
    m = m + m.transpose(0, 2, 1)
    np.testing.assert_array_equal(covariance_from_upper(covariance_to_upper(m)), m)
    assert covariance_to_upper(m).shape == (1, 21)


def test_global_ids_name_vehicle_sensor_and_id() -> None:
    assert global_id("truck-07", "lidar_top", 2**40) == "truck-07/lidar_top/1099511627776"
    ids = np.array([3, 9], dtype=np.int64)
    assert global_ids("v", "s", ids) == ["v/s/3", "v/s/9"]


def test_a_republished_track_frame_keeps_all_but_its_publisher_epoch_and_time() -> None:
    tracks = _arrays()
    kw: dict[str, Any] = dict(
        vehicle="truck-07", sensor="lidar_top", seq=1, stamp_ns=5, frame_id="world",
        pose=None, key_frame=True, instance="svc", received_ns=6, published_ns=7,
        tracks=tracks,
    )  # fmt: skip
    old = encode_track_frame(**kw, epoch=5)
    again = restamp_tracks(old, "svc-b", 6, 99)
    assert again == encode_track_frame(**{**kw, "instance": "svc-b", "published_ns": 99}, epoch=6)
    no_epoch = encode_track_frame(**kw, schema_version=2)  # a reader of before the epoch
    assert _decode(restamp_tracks(no_epoch, "svc-b", 6, 99) or b"")[0].epoch is None
