"""The custody epoch on the wire (TrackFrame version 3, VehicleTrackFrame version 2): written
only when given and only in a version that has it, so every message without one keeps the
bytes of before; read back as ``.epoch`` (None when absent); refused by the table of a
version without it, as a reader of that version refuses it (schemas/README.md, Versioning)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import msgpack
import pytest

from simpletrack.wire import (
    Rejection,
    decode_track_frame,
    decode_vehicle_track_frame,
    encode_track_frame,
    generate,
)
from simpletrack.wire.codec import pack
from simpletrack.wire.fields import Invalid
from simpletrack.wire.messages import TRACK_FRAME_V2, VEHICLE_TRACK_FRAME_V1

VECTORS = Path(generate.__file__).resolve().parents[2] / "vectors"


def _map(payload: bytes) -> dict[str, Any]:
    obj: dict[str, Any] = msgpack.unpackb(payload, raw=False)
    return obj


def test_without_an_epoch_every_message_keeps_its_bytes() -> None:
    assert generate._tracks(2) == (VECTORS / "tracks_v2.msgpack").read_bytes()
    assert generate._tracks(1) == (VECTORS / "tracks_basic.msgpack").read_bytes()
    vehicle = (VECTORS / "vehicle_tracks_basic.msgpack").read_bytes()
    assert generate._vehicle_tracks() == vehicle
    assert _map(vehicle)["schema_version"] == 1


def test_an_epoch_makes_the_version_that_carries_it_and_comes_back() -> None:
    obj = _map(generate._tracks(3, epoch=2**63 - 1))
    assert (obj["schema_version"], list(obj)[-1], obj["epoch"]) == (3, "epoch", 2**63 - 1)
    out = decode_track_frame(generate._tracks(3, epoch=0))
    assert not isinstance(out, Rejection)
    assert (out[0].schema_version, out[0].epoch) == (3, 0)
    vehicle = decode_vehicle_track_frame(generate._vehicle_tracks(epoch=12))
    assert not isinstance(vehicle, Rejection)
    assert (vehicle[0].schema_version, vehicle[0].epoch) == (2, 12)


def test_left_to_choose_the_encoder_sends_3_with_ages_and_an_epoch() -> None:
    kw = _map(generate._tracks(2))
    frame = decode_track_frame(generate._tracks(2))
    assert not isinstance(frame, Rejection)
    payload = encode_track_frame(
        **{k: kw[k] for k in ("vehicle", "sensor", "seq", "stamp_ns", "frame_id", "pose")},
        key_frame=True,
        instance="simpletrack-a",
        received_ns=1,
        published_ns=2,
        tracks=frame[1],
        epoch=4,
    )
    assert (_map(payload)["schema_version"], _map(payload)["epoch"]) == (3, 4)


@pytest.mark.parametrize("version", [1, 2])
def test_a_version_without_the_field_leaves_the_epoch_out(version: int) -> None:
    # What a service at tracks_schema_version 1 or 2 sends: the bytes its readers take.
    assert generate._tracks(version, epoch=9) == generate._tracks(version)


def test_a_version_3_frame_without_an_epoch_or_with_nil_reads_as_none() -> None:
    for epoch in (None, "nil"):
        obj = _map(generate._tracks(3))
        assert obj["schema_version"] == 3 and "epoch" not in obj
        if epoch == "nil":
            obj["epoch"] = None
        out = decode_track_frame(pack(obj))
        assert not isinstance(out, Rejection) and out[0].epoch is None


@pytest.mark.parametrize("bad", [-1, 2**63, True, 1.0, "3"])
def test_the_encoders_refuse_what_no_reader_could_take(bad: Any) -> None:
    with pytest.raises(
        ValueError, match=f"epoch must be an int in \\[0, 2\\*\\*63 - 1\\], got {bad!r}"
    ):
        generate._tracks(3, epoch=bad)
    with pytest.raises(ValueError, match="epoch must be"):
        generate._vehicle_tracks(epoch=bad)


@pytest.mark.parametrize(("value", "reason"), [(-1, "invalid_value"), ("1", "wrong_type")])
def test_a_bad_epoch_is_refused_naming_the_field(value: Any, reason: str) -> None:
    for payload, decode in (
        (generate._tracks(3, epoch=1), decode_track_frame),
        (generate._vehicle_tracks(epoch=1), decode_vehicle_track_frame),
    ):
        obj = _map(payload)
        obj["epoch"] = value
        out = decode(pack(obj))  # type: ignore[operator]
        assert isinstance(out, Rejection)
        assert (out.reason.value, out.field) == (reason, "epoch")


def test_a_reader_of_the_previous_version_refuses_an_epoch() -> None:
    # The field tables of TrackFrame 2 and VehicleTrackFrame 1: what an old reader checks.
    obj = _map(generate._tracks(3, epoch=1))
    obj["schema_version"] = 2
    with pytest.raises(Invalid) as info:
        TRACK_FRAME_V2(obj)
    assert (info.value.reason.value, info.value.field) == ("extra_field", "epoch")
    vehicle = _map(generate._vehicle_tracks(epoch=1))
    vehicle["schema_version"] = 1
    with pytest.raises(Invalid) as info:
        VEHICLE_TRACK_FRAME_V1(vehicle)
    assert (info.value.reason.value, info.value.field) == ("extra_field", "epoch")
