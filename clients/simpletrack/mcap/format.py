"""How the service's messages sit in an MCAP file: one channel per Zenoh key, the payload bytes
as they travelled (message encoding ``msgpack``, in the MCAP registry), described by the
message's JSON Schema (schema encoding ``jsonschema``), generated from the wire models so an
installed package needs no schema files.

Keys: a sensor's ``<prefix>/<vehicle>/<sensor>/{detections,tracks,errors}`` and a fused
vehicle's ``<prefix>/<vehicle>/@vehicle/tracks`` (a ``VehicleTrackFrame``). ``@vehicle`` is a
verbatim chunk that no ``*`` matches, so recording a vehicle (``<vehicle>/*``) or the fleet
(``*/*``) subscribes to it by name (``recorded_keys``)."""

from __future__ import annotations

import functools
import importlib.metadata

import zenoh

from simpletrack.wire.keys import DETECTIONS, ERRORS, TRACKS, VEHICLE_STREAM

MESSAGE_ENCODING = "msgpack"
SCHEMA_ENCODING = "jsonschema"
LEAVES = (DETECTIONS, TRACKS, ERRORS)
# The wire model each key leaf carries (schemas/json/<name>.schema.json).
SCHEMA_NAMES = {DETECTIONS: "DetectionFrame", TRACKS: "TrackFrame", ERRORS: "FrameError"}
# What a fused vehicle's tracks key (<prefix>/<vehicle>/@vehicle/tracks) carries.
VEHICLE_SCHEMA = "VehicleTrackFrame"
# The header profile of a ROS 2 bag (record --ros2 writes one beside the recording).
ROS2_PROFILE = "ros2"
METADATA_NAME = "simpletrack"
TOOL = "simpletrack record"


@functools.cache
def schema_data(name: str) -> bytes:
    """The JSON Schema text of a wire model (``schema_name``'s answer)."""
    from simpletrack.wire.generate import json_schemas

    return json_schemas()[f"{name}.schema.json"].encode()


def schema_name(sensor: str, leaf: str) -> str:
    """The wire model a ``<vehicle>/<sensor>/<leaf>`` key carries."""
    return VEHICLE_SCHEMA if sensor == VEHICLE_STREAM else SCHEMA_NAMES[leaf]


def version() -> str:
    try:
        return importlib.metadata.version("simpletrack-service")
    except importlib.metadata.PackageNotFoundError:  # run from a checkout
        return "unknown"


def split_key(key: str) -> tuple[str, str, str, str] | None:
    """(prefix, vehicle, sensor, leaf) of a ``<prefix>/<vehicle>/<sensor>/<leaf>`` key; a fused
    vehicle's tracks give ``sensor`` ``@vehicle``; None for any other key (``@vehicle`` has
    tracks only)."""
    parts = key.split("/")
    if len(parts) < 4 or parts[-1] not in LEAVES:
        return None
    if parts[-2] == VEHICLE_STREAM and parts[-1] != TRACKS:
        return None
    return "/".join(parts[:-3]), parts[-3], parts[-2], parts[-1]


def recorded_keys(prefix: str, sensors: list[tuple[str, str]], what: list[str]) -> list[str]:
    """The key expressions recording ``sensors`` (``(vehicle, sensor)``, ``*`` allowed in either
    place, or ``(vehicle, "@vehicle")`` for a fused vehicle's tracks alone) and ``what`` (key
    leaves) subscribes to: a whole vehicle (sensor ``*``) brings its fused tracks when ``what``
    has tracks. A key that another one covers is left out (one subscription per sample: two
    would write each sample twice)."""
    keys: list[str] = []
    for vehicle, sensor in sensors:
        if sensor != VEHICLE_STREAM:
            keys += [f"{prefix}/{vehicle}/{sensor}/{leaf}" for leaf in what]
        if sensor in ("*", VEHICLE_STREAM) and TRACKS in what:
            keys.append(f"{prefix}/{vehicle}/{VEHICLE_STREAM}/{TRACKS}")
    unique = list(dict.fromkeys(keys))
    exprs = [zenoh.KeyExpr(k) for k in unique]
    out = []
    for i, expr in enumerate(exprs):
        covered = any(
            other.includes(expr) and (j < i or not expr.includes(other))  # equal: the first
            for j, other in enumerate(exprs)
            if j != i
        )
        if not covered:
            out.append(unique[i])
    return out
