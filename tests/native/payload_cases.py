"""Payloads to hold a client's decoders to the reference decoder's verdicts: every golden
vector, each field of a valid message replaced by values of every msgpack type and of the
edges of its range, deleted, or joined by unknown keys, column contents at their bounds,
poses rigid or not, and random byte damage. Deterministic (a fixed seed)."""

from __future__ import annotations

import math
import random
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import msgpack
import numpy as np

from simpletrack.wire.codec import pack

VECTORS = Path(__file__).resolve().parents[2] / "schemas" / "vectors"
KIND = {"DetectionFrame": "D", "TrackFrame": "T", "VehicleTrackFrame": "V", "FrameError": "E"}
# Each column's dtype where it is not <f4 (or <i4 for the integer ones).
_DTYPES = {
    "id": "<i8",
    "score": "<f8",
    "age_s": "<f8",
    "time_since_update_s": "<f8",
    "existence": "<f8",
    "sensor_stamp_ns": "<i8",
}
_INTEGER = ("class_index", "id", "state", "hits", "age", "time_since_update", "sensor_stamp_ns")

# One of each msgpack type, and the edges of the wire's ranges.
VALUES: list[Any] = [
    None, True, False, 0, 1, -1, 2**31 - 1, 2**31, 2**63 - 1, 2**63, 2**64 - 1, -(2**63),
    1.0, 1.5, -0.0, math.nan, math.inf, "", "x", "veh-1", "a/b", ".x", "x\n", "é" * 64,
    "é" * 65, "x" * 129, "Car", "missed", b"", b"missed", b"\x00" * 12, [], ["Car"], [1.0] * 16,
    [1] * 16, [1.0] * 15, [None, 3], {}, {"a": 1}, msgpack.ExtType(5, b"x"),
    msgpack.Timestamp(1, 0),
]  # fmt: skip

_F4 = [math.nan, math.inf, -math.inf, 0.0, -1.0, 1e5, 100001.0, 3.4e38, 100.0, 100.5, 1e4,
       10001.0, 200.0, 200.5, -200.5, -0.0]  # fmt: skip

_EYE = [1.0, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 1.0]


def _poses() -> list[list[Any]]:
    c, s = math.cos(0.3), math.sin(0.3)
    rot = [c, -s, 0.0, 5.0, s, c, 0.0, -3.0, 0.0, 0.0, 1.0, 1.0, 0.0, 0.0, 0.0, 1.0]
    out: list[list[Any]] = [_EYE, rot, [int(v) for v in _EYE]]
    for i, v in [(10, -1.0), (3, 1e5), (7, 100000.5), (12, 0.001), (15, 1.00001), (0, 1.001),
                 (1, math.nan), (11, math.inf), (0, 2.0)]:  # fmt: skip
        p = list(rot)
        p[i] = v
        out.append(p)
    return out


def vectors() -> Iterator[tuple[str, str, bytes]]:
    """(name, kind letter, payload) of every golden vector."""
    import json

    for path in sorted(VECTORS.glob("*.json")):
        kind = KIND[json.loads(path.read_text())["message"]]
        yield path.stem, kind, path.with_suffix(".msgpack").read_bytes()


def _maps(kind: str) -> list[dict[str, Any]]:
    out = []
    for name, k, payload in vectors():
        if k == kind and not name.startswith("invalid_"):
            out.append(msgpack.unpackb(payload, raw=False))
    return out


def _field_cases(obj: dict[str, Any], nested: str | None) -> Iterator[dict[str, Any]]:
    for key in [*obj, "pose", "session_id", "seqs", "extrinsic", "speed"]:
        for value in VALUES:
            yield {**obj, key: value}
        if key in obj:
            yield {k: v for k, v in obj.items() if k != key}
    yield {**obj, b"speed": 1}  # type: ignore[dict-item]
    yield {**obj, "zz": 1, "aa": 2}
    if nested is not None and isinstance(obj.get(nested), dict):
        for inner in _field_cases(obj[nested], None):
            yield {**obj, nested: inner}


def _column_cases(obj: dict[str, Any], nested: str, rng: random.Random) -> Iterator[dict[str, Any]]:
    cols = obj[nested]
    n = cols["count"]
    for name, buf in cols.items():
        if not isinstance(buf, bytes) or n == 0:
            continue
        integer = name in _INTEGER
        dtype = _DTYPES.get(name, "<i4" if integer else "<f4")
        values: list[float] = [-2, -1, 2, 3, 1000, 2**31 - 1] if integer else [*_F4, 0.5, 1.5]
        for v in values:
            arr = np.frombuffer(buf, dtype).copy()
            arr[rng.randrange(len(arr))] = v
            yield {**obj, nested: {**cols, name: arr.tobytes()}}
        yield {**obj, nested: {**cols, name: buf[:-1]}}
        yield {**obj, nested: {**cols, name: buf + buf}}


def _damaged(payload: bytes, rng: random.Random) -> bytes:
    b = bytearray(payload)
    action = rng.randrange(4)
    i = rng.randrange(len(b))
    if action == 0:
        b[i] = rng.randrange(256)
    elif action == 1:
        b[i] ^= 1 << rng.randrange(8)
    elif action == 2:
        del b[i:]
    else:
        b.insert(i, rng.randrange(256))
    return bytes(b)


def cases(seed: int = 7, damaged: int = 600) -> list[tuple[str, bytes]]:
    """(kind letter, payload) pairs."""
    rng = random.Random(seed)
    out = [(kind, payload) for _, kind, payload in vectors()]
    for kind, nested in (("D", "boxes"), ("T", "tracks"), ("V", "tracks"), ("E", None)):
        for obj in _maps(kind):
            out += [(kind, pack(m)) for m in _field_cases(obj, nested)]
            if nested is not None:
                out += [(kind, pack(m)) for m in _column_cases(obj, nested, rng)]
            if kind in "DTV":
                out += [(kind, pack({**obj, "pose": p})) for p in _poses()]
            if kind == "D":
                out += [(kind, pack({**obj, "extrinsic": p})) for p in _poses()]
    valid = list(out[: len(out)])
    for _ in range(damaged):
        kind, payload = valid[rng.randrange(len(valid))]
        if payload:
            out.append((kind, _damaged(payload, rng)))
    return out
