"""``peek_header`` (drop notices) answers what the full decoder reads, on valid and damaged
payloads alike, and never raises."""

from __future__ import annotations

import random
from pathlib import Path

import msgpack
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from simpletrack.wire.codec import Rejection, decode_detection_frame
from simpletrack.wire.header import MAX_BYTES, peek_header

VECTORS = sorted((Path(__file__).resolve().parents[2] / "schemas" / "vectors").glob("*.msgpack"))


def decoder_reads(payload: bytes) -> tuple[int | None, int | None]:
    """What drop notices reported before peek_header: the full decode's seq and stamp_ns."""
    r = decode_detection_frame(payload)
    if isinstance(r, Rejection):
        return r.seq, r.stamp_ns
    return r.frame.seq, r.frame.stamp_ns


def damaged(payload: bytes, rng: random.Random) -> bytes:
    b = bytearray(payload)
    kind = rng.randrange(4)
    if kind == 0 and b:  # flip a few bytes
        for _ in range(rng.randint(1, 3)):
            b[rng.randrange(len(b))] = rng.randrange(256)
    elif kind == 1:  # truncated
        del b[rng.randrange(len(b) + 1) :]
    elif kind == 2:  # trailing bytes
        b += bytes(rng.randrange(256) for _ in range(rng.randint(1, 4)))
    else:  # bytes inserted
        at = rng.randrange(len(b) + 1)
        b[at:at] = bytes(rng.randrange(256) for _ in range(rng.randint(1, 4)))
    return bytes(b)


def test_there_are_golden_vectors_with_and_without_a_readable_seq() -> None:
    seqs = {peek_header(p.read_bytes())[0] is None for p in VECTORS}
    assert len(VECTORS) >= 10 and seqs == {True, False}


@pytest.mark.parametrize("path", VECTORS, ids=[p.stem for p in VECTORS])
def test_golden_vector_header_is_what_the_decoder_reads(path: Path) -> None:
    payload = path.read_bytes()
    assert peek_header(payload) == decoder_reads(payload)


@pytest.mark.parametrize("path", VECTORS, ids=[p.stem for p in VECTORS])
def test_damaged_golden_vector_header_is_what_the_decoder_reads(path: Path) -> None:
    rng = random.Random(path.stem)
    payload = path.read_bytes()
    for _ in range(300):
        bad = damaged(payload, rng)
        assert peek_header(bad) == decoder_reads(bad), bad.hex()


@settings(max_examples=300, deadline=None)
@given(st.binary(max_size=256))
def test_random_bytes_never_raise_and_match_the_decoder(data: bytes) -> None:
    assert peek_header(data) == decoder_reads(data)


SCALARS = st.none() | st.booleans() | st.integers(-(2**63), 2**64 - 1) | st.floats() | st.text()
VALUES = st.recursive(
    SCALARS | st.binary(max_size=8),
    lambda inner: st.lists(inner, max_size=3) | st.dictionaries(st.text(max_size=4), inner),
    max_leaves=8,
)


@settings(max_examples=300, deadline=None)
@given(st.dictionaries(st.sampled_from(["seq", "stamp_ns", "boxes", "vehicle"]), VALUES))
def test_any_map_gives_the_decoder_s_seq_and_stamp(obj: dict[str, object]) -> None:
    payload = msgpack.packb(obj, use_bin_type=True)
    assert peek_header(payload) == decoder_reads(payload)


@pytest.mark.parametrize(
    ("obj", "expected"),
    [
        pytest.param({"seq": 3, "stamp_ns": 9}, (3, 9), id="both ints"),
        pytest.param({"seq": -1, "stamp_ns": 2**63}, (None, None), id="outside int64 range"),
        pytest.param({"seq": True, "stamp_ns": 1.0}, (None, None), id="bool and float"),
        pytest.param({"seq": "3"}, (None, None), id="a string seq"),
        pytest.param([3, 9], (None, None), id="not a map"),
        pytest.param({"seq": 3, "vehicle": {1: "x"}}, (None, None), id="non-string key inside"),
    ],
)
def test_header_values_are_read_only_when_well_typed(obj: object, expected: tuple) -> None:
    payload = msgpack.packb(obj, use_bin_type=True, strict_types=False)
    assert peek_header(payload) == expected == decoder_reads(payload)


def test_a_broken_string_anywhere_leaves_the_header_unread() -> None:
    # Like the decoder: the map could not be read, so neither can its seq.
    payload = msgpack.packb({"seq": 3, "boxes": {"classes": ["Car"]}}).replace(b"Car", b"C\xffr")
    assert peek_header(payload) == (None, None) == decoder_reads(payload)


def test_a_payload_over_the_decoder_s_byte_cap_is_not_read() -> None:
    payload = msgpack.packb({"seq": 3, "stamp_ns": 9, "pad": b"x" * MAX_BYTES})
    assert peek_header(payload) == (None, None) == decoder_reads(payload)
    assert peek_header(msgpack.packb({"seq": 3, "stamp_ns": 9})) == (3, 9)


@pytest.mark.parametrize("version", [1, 2, 3])
def test_peek_heard_reads_what_the_full_decoder_reads_of_a_tracks_message(version: int) -> None:
    from simpletrack.wire import decode_track_frame, generate
    from simpletrack.wire.header import peek_heard

    for epoch in (None, 7) if version == 3 else (None,):
        payload = generate._tracks(version, epoch=epoch) if epoch else generate._tracks(version)
        out = decode_track_frame(payload)
        assert not isinstance(out, Rejection)
        frame, tracks = out
        next_id = int(tracks.id.max()) + 1 if len(tracks) else 0
        assert peek_heard(payload) == (frame.stamp_ns, next_id, frame.epoch)


@given(st.binary(max_size=300))
@settings(max_examples=200, deadline=None)
def test_peek_heard_never_raises_and_reads_nothing_from_garbage(payload: bytes) -> None:
    from simpletrack.wire.header import peek_heard

    assert peek_heard(payload) is None


def test_peek_heard_refuses_an_id_column_that_does_not_match_its_count() -> None:
    from simpletrack.wire import generate
    from simpletrack.wire.header import peek_heard

    obj = msgpack.unpackb(generate._tracks(2), raw=False)
    obj["tracks"]["id"] = obj["tracks"]["id"][:-1]
    assert peek_heard(msgpack.packb(obj)) is None
    obj["tracks"]["count"] = 0
    obj["tracks"]["id"] = b""
    assert peek_heard(msgpack.packb(obj))[1] == 0  # type: ignore[index]


def test_peek_written_reads_a_checkpoint_s_written_ns_and_nothing_from_garbage() -> None:
    from simpletrack.wire.codec import encode
    from simpletrack.wire.header import peek_written
    from simpletrack.wire.models import SensorSnapshot

    snap = SensorSnapshot(
        schema_version=1, vehicle="v", sensor="s", config_digest="d", written_ns=1234,
        last_seq=3, last_stamp_ns=300, id_base=0, id_next=5, frames=0, tracker=b"t",
    )  # fmt: skip
    assert peek_written(encode(snap)) == 1234
    assert peek_written(b"\xc1 garbage") is None
    assert peek_written(msgpack.packb({"written_ns": -1})) is None
    assert peek_written(msgpack.packb([1234])) is None


@pytest.mark.parametrize("empty", [False, True])
@pytest.mark.parametrize("epoch", [None, 7])
def test_peek_vehicle_heard_reads_what_the_full_decoder_reads(
    empty: bool, epoch: int | None
) -> None:
    from simpletrack.wire import generate
    from simpletrack.wire.header import peek_vehicle_heard
    from simpletrack.wire.vehicle_tracks import decode_vehicle_track_frame

    payload = generate._vehicle_tracks(empty=empty, epoch=epoch)
    out = decode_vehicle_track_frame(payload)
    assert not isinstance(out, Rejection)
    frame, tracks = out
    next_id = int(tracks.id.max()) + 1 if len(tracks) else 0
    assert peek_vehicle_heard(payload) == (frame.stamp_ns, next_id, frame.seq, frame.epoch)


@given(st.binary(max_size=300))
@settings(max_examples=200, deadline=None)
def test_peek_vehicle_heard_never_raises_and_reads_nothing_from_garbage(payload: bytes) -> None:
    from simpletrack.wire.header import peek_vehicle_heard

    assert peek_vehicle_heard(payload) is None


def test_peek_vehicle_heard_needs_the_vehicle_s_seq_and_an_id_column_of_its_count() -> None:
    from simpletrack.wire import generate
    from simpletrack.wire.header import peek_vehicle_heard

    obj = msgpack.unpackb(generate._vehicle_tracks(), raw=False)
    assert peek_vehicle_heard(msgpack.packb(obj)) is not None
    for broken in ({"seq": -1}, {"seq": "1042"}, {"tracks": {**obj["tracks"], "count": 3}}):
        assert peek_vehicle_heard(msgpack.packb({**obj, **broken})) is None
    del obj["seq"]
    assert peek_vehicle_heard(msgpack.packb(obj)) is None
