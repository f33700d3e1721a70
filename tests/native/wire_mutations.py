"""Damaged and odd payloads, made deterministically from the golden vectors, for holding
another language's decoder to the Python decoder's verdicts (reason, field, seq, stamp_ns).

Maps are packed pair by pair, so that a payload can repeat a key, carry a ``bin`` or int key,
or hold raw msgpack the Python packer would never write (float32, a positive int in a signed
format, bad UTF-8, lists nested 1024 deep).
"""

from __future__ import annotations

import copy
import random
import struct
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import msgpack
import numpy as np

VECTORS = Path(__file__).resolve().parents[2] / "schemas" / "vectors"
VALID = (
    "detection_basic",
    "detection_full",
    "detection_empty",
    "detection_extrinsic",
    "tracks_basic",
    "tracks_v2",
    "tracks_epoch",
    "vehicle_tracks_basic",
    "vehicle_tracks_empty",
    "vehicle_tracks_epoch",
    "error_unknown_class",
    "error_sensor_flagged",
)


@dataclass(frozen=True)
class Raw:
    """Bytes inserted verbatim where a key or value goes."""

    data: bytes


def pack(obj: Any) -> bytes:
    if isinstance(obj, Raw):
        return obj.data
    if isinstance(obj, Pairs):
        return pack_pairs(obj.items)
    if isinstance(obj, list) and any(isinstance(v, Raw | Pairs) for v in obj):
        return _array_header(len(obj)) + b"".join(pack(v) for v in obj)
    return bytes(msgpack.packb(obj, use_bin_type=True))


@dataclass(frozen=True)
class Pairs:
    """A map as a list of (key, value) pairs: keys may repeat or be of any type."""

    items: list[tuple[Any, Any]]


def _map_header(n: int) -> bytes:
    return bytes([0x80 | n]) if n < 16 else b"\xde" + struct.pack(">H", n)


def _array_header(n: int) -> bytes:
    return bytes([0x90 | n]) if n < 16 else b"\xdc" + struct.pack(">H", n)


def pack_pairs(items: list[tuple[Any, Any]]) -> bytes:
    return _map_header(len(items)) + b"".join(pack(k) + pack(v) for k, v in items)


def f32(v: float) -> Raw:
    return Raw(b"\xca" + struct.pack(">f", v))


def _column(values: Any, dtype: str) -> bytes:
    return np.asarray(values, dtype=np.dtype(dtype)).tobytes()


EYE = [1.0, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 1.0]
REFLECTION = [*EYE[:10], -1.0, *EYE[11:]]
FAR = [*EYE[:3], 2e5, *EYE[4:]]
SKEWED = [1.0, 0.001, *EYE[2:]]
NAN_POSE = [*EYE[:5], float("nan"), *EYE[6:]]
C, S = 0.6, 0.8  # a rotation about z, exact enough in float32 too
TURNED = [C, -S, 0.0, 5.0, S, C, 0.0, -3.0, 0.0, 0.0, 1.0, 1.0, 0.0, 0.0, 0.0, 1.0]
POSES: list[Any] = [
    EYE,
    REFLECTION,
    FAR,
    SKEWED,
    NAN_POSE,
    TURNED,
    [f32(v) for v in TURNED],
    [*EYE[:12], 0.0, 0.0, 1e-5, 1.0],
    [*EYE[:12], 0.0, 0.0, 0.0, 1.001],
    None,
]

# Values any field may be set to: every msgpack type, at and beyond each range's ends.
VALUES: list[Any] = [
    None,
    True,
    False,
    0,
    1,
    2,
    -1,
    7,
    2**31 - 1,
    2**31,
    2**63 - 1,
    2**63,
    2**64 - 1,
    -(2**63),
    0.5,
    1.0,
    float("nan"),
    float("inf"),
    f32(1.0),
    f32(0.25),
    Raw(b"\xd0\x01"),
    Raw(b"\xd3" + struct.pack(">q", 1)),
    Raw(b"\xd0\xff"),  # signed formats
    "",
    "x",
    "Car",
    "Pedestrian",
    "Tram",
    "a" * 64,
    "a" * 65,
    "é" * 64,
    "é" * 65,
    "a" * 129,
    "veh-1",
    "bad/name",
    "_ok.name-1",
    ".dot",
    "line\n",
    "missed",
    "future_reason",
    Raw(b"\xa2\xed\xa0"),
    Raw(b"\xa1\xff"),  # str that is not UTF-8
    b"",
    b"\x00" * 4,
    b"x" * 12,
    b"missed",
    b"\xff\xfe",
    [],
    ["Car"],
    ["Car", 1],
    ["Car", ""],
    ["Car", None],
    ["a"] * 1025,
    [None, 3, -1],
    EYE,
    REFLECTION,
    FAR,
    SKEWED,
    NAN_POSE,
    EYE[:15],
    [*EYE, 0.0],
    [1] * 16,
    [*EYE[:4], "x", *EYE[5:]],
    [f32(v) for v in EYE],
    {},
    {"a": 1},
    Pairs([(1, 2)]),
    Pairs([(b"k", 1)]),
    msgpack.ExtType(5, b"x"),
    Raw(b"\xd6\xff\x00\x00\x00\x01"),
    Raw(b"\xd5\xff\x00\x01"),
    Raw(b"\xd7\xff" + ((2**30 - 1) << 34).to_bytes(8, "big")),
    Raw(b"\x91" * 1022 + b"\x90"),
    Raw(b"\x91" * 1023 + b"\x90"),
    Raw(b"\x91" * 1023 + b"\x01"),
]

FLOAT_SPECIALS = [
    0.0,
    -0.0,
    1.0,
    -1.0,
    1e5,
    100000.01,
    100.0,
    100.01,
    200.0,
    200.5,
    1e4,
    1e4 + 1,
    3.4e38,
    float("nan"),
    float("inf"),
    -float("inf"),
    1e-45,
]
COLUMN_WIDTHS = {
    "class_index": ("<i4", 1),
    "center": ("<f4", 3),
    "size": ("<f4", 3),
    "yaw": ("<f4", 1),
    "score": ("<f8", 1),
    "velocity": ("<f4", 2),
    "id": ("<i8", 1),
    "state": ("<i4", 1),
    "hits": ("<i4", 1),
    "age": ("<i4", 1),
    "time_since_update": ("<i4", 1),
    "covariance": ("<f4", 21),
    "age_s": ("<f8", 1),
    "time_since_update_s": ("<f8", 1),
    "existence": ("<f8", 1),
    "sensor_stamp_ns": ("<i8", 2),  # the basic vehicle vector's two sensors
}
EXTRA_KEYS = [
    "speed",
    "Seq",
    "",
    "boxes ",
    "velocity",
    "pose",
    "session_id",
    "seqs",
    "extrinsic",
    "existence",
    "key_frame",
]


def _value(rng: random.Random) -> Any:
    # A copy: a shared Pairs edited in one payload (or set inside itself) would recurse.
    return copy.deepcopy(rng.choice(VALUES))


def bases() -> list[bytes]:
    return [(VECTORS / f"{name}.msgpack").read_bytes() for name in VALID]


def _pairs(payload: bytes) -> list[tuple[Any, Any]]:
    obj: dict[str, Any] = msgpack.unpackb(payload, raw=False)
    return [(k, _pairs_of(v)) for k, v in obj.items()]


def _pairs_of(v: Any) -> Any:
    return Pairs([(k, _pairs_of(x)) for k, x in v.items()]) if isinstance(v, dict) else v


def _nested(pairs: list[tuple[Any, Any]]) -> list[tuple[Any, Any]] | None:
    for _, v in pairs:
        if isinstance(v, Pairs):
            return v.items
    return None


def _bad_column(rng: random.Random, name: str, count: int) -> bytes:
    dtype, width = COLUMN_WIDTHS.get(name, ("<f4", 1))
    n = count * width
    roll = rng.random()
    if roll < 0.2:  # wrong length
        return bytes(rng.randrange(256) for _ in range(rng.choice([0, 1, 3, 4, 8, n * 4 + 4])))
    if dtype.startswith("<i"):
        ints = [rng.choice([0, 1]) for _ in range(n)]
        if ints and rng.random() < 0.7:
            ints[rng.randrange(n)] = rng.choice([2, 3, -1, -2, 2**31 - 1, -(2**31)])
        return _column(ints, dtype)
    floats = [rng.uniform(0.1, 5) for _ in range(n)]
    if floats:  # one odd value, in any row
        floats[rng.randrange(n)] = rng.choice([*FLOAT_SPECIALS, 0.5, 1.5])
    return _column(floats, dtype)


def _mutate_map(rng: random.Random, items: list[tuple[Any, Any]], nested: bool) -> None:
    roll = rng.random()
    if nested and roll < 0.5:
        roll = 0.9  # mostly columns: the checks after the fields' types
    elif not nested and roll < 0.1:
        items.append((rng.choice(["pose", "pose", "extrinsic"]), rng.choice(POSES)))
        return
    if roll < 0.45 and items:  # a field set to an odd value
        i = rng.randrange(len(items))
        items[i] = (items[i][0], _value(rng))
    elif roll < 0.6 and items:  # a field dropped
        del items[rng.randrange(len(items))]
    elif roll < 0.7:  # an unknown, repeated, bin or int key
        key = rng.choice(
            [*EXTRA_KEYS, *(k for k, _ in items), b"speed", Raw(b"\x01"), Raw(b"\xc0")]
        )
        items.insert(rng.randrange(len(items) + 1), (key, _value(rng)))
    elif roll < 0.8:  # the same keys in another order
        rng.shuffle(items)
    else:  # a column with bad lengths or values, or a changed count
        keys = [k for k, v in items if isinstance(v, bytes)]
        count = next((v for k, v in items if k == "count" and isinstance(v, int)), 3)
        count = count if 0 <= count <= 64 else 3  # a huge count edited earlier: keep columns small
        if keys and rng.random() < 0.8:
            k = rng.choice(keys)
            i = next(j for j, (kk, _) in enumerate(items) if kk == k)
            items[i] = (k, _bad_column(rng, k, count))
        else:
            for j, (k, _) in enumerate(items):
                if k == "count":
                    items[j] = (k, rng.choice([0, 1, 2, 4, 10_001, 2**31 - 1, 2**31, -1, 3.0]))


def mutations(seed: int = 0, n: int = 3000) -> Iterator[bytes]:
    """``n`` payloads: one to three structural edits of a valid message, or damaged bytes."""
    rng = random.Random(seed)
    originals = bases()
    yield from originals
    for _ in range(n):
        base = rng.choice(originals)
        if rng.random() < 0.15:  # byte damage
            b = bytearray(base)
            kind = rng.randrange(4)
            if kind == 0:
                del b[rng.randrange(len(b)) :]
            elif kind == 1:
                b[rng.randrange(len(b))] = rng.randrange(256)
            elif kind == 2:
                b += bytes(rng.randrange(256) for _ in range(rng.randint(1, 3)))
            else:
                b = bytearray(rng.randrange(256) for _ in range(rng.randint(0, 40)))
            yield bytes(b)
            continue
        top = _pairs(base)
        for _ in range(rng.randint(1, 3)):
            nested = _nested(top)
            inner = nested is not None and rng.random() < 0.5
            _mutate_map(rng, nested if inner and nested is not None else top, inner)
        yield pack_pairs(top)
