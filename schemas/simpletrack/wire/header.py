"""``seq`` and ``stamp_ns`` of a detection frame without validating it, for the notices of
frames the service sheds under load (it must not pay a full decode exactly then).

Same answer as the full decoder's on every payload: a valid frame gives its values; a damaged
one gives them when its msgpack map could still be read and they are in range, else None.
That is why the payload is still parsed as a whole (msgpack's C parser; the box columns stay
raw bytes: no models, no arrays): any broken string or key anywhere makes the decoder read
nothing, and skipping values unread would answer where it does not.
"""

from __future__ import annotations

from typing import Any

import msgpack
import numpy as np

# The decoder's default byte cap, which drop notices have always been read with.
MAX_BYTES = 8 << 20
_INT64_END = 2**63


def _int64(obj: dict[Any, Any], key: str) -> int | None:
    v = obj.get(key)
    return v if type(v) is int and 0 <= v < _INT64_END else None


def _map(payload: bytes) -> dict[Any, Any] | None:
    """The payload's msgpack map, parsed whole; None for garbage of any kind, anything but a
    map, or a payload over the decoder's byte cap. Never raises."""
    if len(payload) > MAX_BYTES:
        return None
    try:
        obj = msgpack.unpackb(payload, raw=False, strict_map_key=True)
    except Exception:  # garbage of any kind: nothing to report
        return None
    return obj if isinstance(obj, dict) else None


def peek_header(payload: bytes) -> tuple[int | None, int | None]:
    """(seq, stamp_ns) of a payload, each None when it cannot be read. Never raises."""
    obj = _map(payload)
    return (None, None) if obj is None else (_int64(obj, "seq"), _int64(obj, "stamp_ns"))


def peek_custody(payload: bytes) -> tuple[str | None, int | None]:
    """(instance, epoch) of a tracks message (TrackFrame or VehicleTrackFrame) without
    validating it: who published it, in which custody epoch (None: not there or unreadable).
    A member reads it from the tracks of the streams it holds, published by another one:
    a higher epoch there means its own state is stale (docs/SCALE.md, "Fencing")."""
    obj = _map(payload)
    if obj is None:
        return None, None
    instance = obj.get("instance")
    return (instance if isinstance(instance, str) else None), _int64(obj, "epoch")


def peek_written(payload: bytes) -> int | None:
    """``written_ns`` of a SensorSnapshot (a checkpoint) without validating it: which of two
    states of one sensor is the newer. None when it cannot be read."""
    obj = _map(payload)
    return None if obj is None else _int64(obj, "written_ns")


def peek_heard(payload: bytes) -> tuple[int, int, int | None] | None:
    """(stamp_ns, next id: the highest track id + 1, 0 for none; epoch) of a TrackFrame,
    for a standby that only needs how far planners have it: one msgpack parse and the id
    column, no validation of the other columns (the full decoder costs ~10x this on every
    frame the owner publishes). None when those two cannot be read."""
    obj = _map(payload)
    return None if obj is None else _heard_of(obj)


def peek_vehicle_heard(payload: bytes) -> tuple[int, int, int, int | None] | None:
    """(stamp_ns, next id, seq, epoch) of a VehicleTrackFrame, read as ``peek_heard`` reads
    a TrackFrame, with the vehicle's own message counter ``seq`` (the full decoder costs ~8x
    this). None when those three cannot be read."""
    obj = _map(payload)
    if obj is None:
        return None
    heard, seq = _heard_of(obj), _int64(obj, "seq")
    if heard is None or seq is None:
        return None
    stamp, next_id, epoch = heard
    return stamp, next_id, seq, epoch


def _heard_of(obj: dict[Any, Any]) -> tuple[int, int, int | None] | None:
    stamp, tracks = _int64(obj, "stamp_ns"), obj.get("tracks")
    if stamp is None or not isinstance(tracks, dict):
        return None
    count, ids = tracks.get("count"), tracks.get("id")
    if type(count) is not int or not isinstance(ids, bytes) or len(ids) != 8 * count:
        return None
    epoch = _int64(obj, "epoch")
    if count == 0:
        return stamp, 0, epoch
    top = int(np.frombuffer(ids, dtype="<i8").max())
    return (stamp, top + 1, epoch) if top >= 0 else None


def restamp_tracks(
    payload: bytes, instance: str, epoch: int | None, published_ns: int
) -> bytes | None:
    """A tracks message (TrackFrame or VehicleTrackFrame) as another member publishes it again:
    its ``instance``, ``published_ns`` and, where it has one, its ``epoch`` replaced, every
    other field (the tracks' columns among them) kept as it was. None when it cannot be read."""
    obj = _map(payload)
    if obj is None or not isinstance(obj.get("tracks"), dict):
        return None
    obj["instance"], obj["published_ns"] = instance, published_ns
    if "epoch" in obj and epoch is not None:
        obj["epoch"] = epoch
    return bytes(msgpack.packb(obj, use_bin_type=True))
