"""``VehicleTrackFrame``: a vehicle's fused tracks (``<prefix>/<vehicle>/@vehicle/tracks``),
encoded and decoded. Decoding never raises: the frame and its columns, or a ``Rejection``.

Order of checks (schemas/README.md, "VehicleTrackFrame"): the payload, the version (1 or 2), the
fields in table order and unknown keys; then across fields: ``sensors`` unique,
``sensor_state`` one per sensor, ``sensor`` one of ``sensors``; then the row cap, each
column's byte length (``sensor_stamp_ns``: count x len(sensors) values) and finiteness in
table order; then ``existence`` within [0, 1] and ``sensor_stamp_ns`` at least -1.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np
import numpy.typing as npt

from simpletrack.wire.codec import check_epoch, pack, packed_around
from simpletrack.wire.columns import VEHICLE_TRACK_COLUMNS, TrackArrays, to_column
from simpletrack.wire.decoding import (
    DEFAULT_LIMITS,
    DecodeLimits,
    Reject,
    Rejection,
    check_version,
    internal_error,
    plan,
    read_columns,
    rejection,
    unpack,
    validate,
)
from simpletrack.wire.messages import VEHICLE_TRACK_FRAMES, VehicleTrackFrame
from simpletrack.wire.reasons import (
    VEHICLE_TRACK_SCHEMA_VERSION,
    VEHICLE_TRACK_SCHEMA_VERSIONS,
    ErrorReason,
    SensorCondition,
)

_PLAN = plan(VEHICLE_TRACK_COLUMNS, "tracks")
# No sensor updated the track (a sensor_stamp_ns value).
NEVER = -1


def _check_sensors(sensor: str, sensors: Sequence[str], states: Sequence[str]) -> None:
    seen: set[str] = set()
    for i, name in enumerate(sensors):
        if name in seen:
            raise Reject(ErrorReason.INVALID_VALUE, "sensors", f"{name!r} repeated at {i}")
        seen.add(name)
    if len(states) != len(sensors):
        raise Reject(
            ErrorReason.INVALID_VALUE,
            "sensor_state",
            f"{len(states)} states for {len(sensors)} sensors",
        )
    if sensor not in seen:
        raise Reject(ErrorReason.INVALID_VALUE, "sensor", f"{sensor!r} is not one of sensors")


def _check_values(existence: npt.NDArray[Any], stamps: npt.NDArray[Any]) -> None:
    outside = (existence < 0) | (existence > 1)
    if outside.any():
        row = int(np.argmax(outside))
        raise Reject(ErrorReason.INVALID_VALUE, "tracks.existence", f"outside [0, 1] in row {row}")
    below = stamps < NEVER
    if below.any():
        row = int(np.argwhere(below)[0][0])
        raise Reject(
            ErrorReason.INVALID_VALUE, "tracks.sensor_stamp_ns", f"below {NEVER} in row {row}"
        )


def decode_vehicle_track_frame(
    payload: bytes,
    limits: DecodeLimits = DEFAULT_LIMITS,
) -> tuple[VehicleTrackFrame, TrackArrays] | Rejection:
    """Decode and validate a ``VehicleTrackFrame`` (version 1, or 2: its ``epoch`` is None
    unless a version-2 frame carries one). The arrays hold every TrackFrame version 2
    column, ``existence`` (N,) and ``sensor_stamp_ns`` (N, len(sensors))."""
    obj: dict[str, Any] = {}
    try:
        obj = unpack(payload, limits)
        version = check_version(obj, VEHICLE_TRACK_SCHEMA_VERSIONS)
        frame = validate(VEHICLE_TRACK_FRAMES[version], obj)
        _check_sensors(frame.sensor, frame.sensors, frame.sensor_state)
        cols = read_columns(frame.tracks, _PLAN, "tracks", limits.max_boxes, len(frame.sensors))
        _check_values(cols["existence"], cols["sensor_stamp_ns"])
        return frame, TrackArrays(classes=tuple(frame.tracks.classes), **cols)
    except Reject as r:
        return rejection(r, obj)
    except Exception as e:  # a bug in this module; the fuzz test asserts it never happens
        return internal_error(e)


def encode_vehicle_track_frame(
    *,
    vehicle: str,
    seq: int,
    stamp_ns: int,
    sensor: str,
    sensor_seq: int,
    frame_id: str,
    pose: list[float] | None,
    instance: str,
    received_ns: int,
    published_ns: int,
    sensors: Sequence[str],
    sensor_state: Sequence[SensorCondition | str],
    tracks: TrackArrays | bytes,
    epoch: int | None = None,
) -> bytes:
    """A ``VehicleTrackFrame``; ``tracks`` must hold ``age_s``, ``time_since_update_s``,
    ``existence`` and ``sensor_stamp_ns`` (N, len(sensors)) (``covariance`` is optional, as
    in a TrackFrame). Version 2 with an ``epoch``; without one version 1, byte for byte what
    an encoder of before the epoch wrote. ValueError for a missing or misshapen column, an
    unknown sensor state, repeated sensors, states not one per sensor, ``sensor`` not among
    ``sensors``, or an epoch outside [0, 2**63 - 1]. ``tracks`` as bytes is the ``tracks`` map
    packed already (wire/convert.py ``pack_vehicle_tracks_checked``), put in as it is."""
    check_epoch(epoch)
    names = [str(s) for s in sensors]
    states = [SensorCondition(s).value for s in sensor_state]
    try:
        _check_sensors(sensor, names, states)
    except Reject as r:
        raise ValueError(f"VehicleTrackFrame.{r.field}: {r.detail}") from None
    msg: dict[str, Any] = {
        "schema_version": 1 if epoch is None else VEHICLE_TRACK_SCHEMA_VERSION,
        "vehicle": vehicle,
        "seq": seq,
        "stamp_ns": stamp_ns,
        "sensor": sensor,
        "sensor_seq": sensor_seq,
        "frame_id": frame_id,
        "pose": pose,
        "instance": instance,
        "received_ns": received_ns,
        "published_ns": published_ns,
        "sensors": names,
        "sensor_state": states,
    }
    if isinstance(tracks, bytes):
        return packed_around(msg, tracks, epoch)
    msg["tracks"] = _columns(tracks, names)
    if epoch is not None:
        msg["epoch"] = epoch
    return pack(msg)


def _columns(tracks: TrackArrays, names: list[str]) -> dict[str, Any]:
    columns: dict[str, Any] = {"count": len(tracks), "classes": list(tracks.classes)}
    for spec in VEHICLE_TRACK_COLUMNS:
        values = getattr(tracks, spec.name)
        if values is None:
            if not spec.optional:
                raise ValueError(f"a VehicleTrackFrame needs {spec.name}")
            continue
        columns[spec.name] = to_column(values, spec, len(names))
    return columns
