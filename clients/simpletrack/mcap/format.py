"""How the service's messages sit in an MCAP file: one channel per Zenoh key, the payload bytes
as they travelled (message encoding ``msgpack``, in the MCAP registry), described by the
message's JSON Schema (schema encoding ``jsonschema``), generated from the wire models so an
installed package needs no schema files."""

from __future__ import annotations

import functools
import importlib.metadata

from simpletrack.wire.keys import DETECTIONS, ERRORS, TRACKS

MESSAGE_ENCODING = "msgpack"
SCHEMA_ENCODING = "jsonschema"
LEAVES = (DETECTIONS, TRACKS, ERRORS)
# The wire model each key leaf carries (schemas/json/<name>.schema.json).
SCHEMA_NAMES = {DETECTIONS: "DetectionFrame", TRACKS: "TrackFrame", ERRORS: "FrameError"}
METADATA_NAME = "simpletrack"
TOOL = "simpletrack record"


@functools.cache
def schema_data(leaf: str) -> bytes:
    """The JSON Schema text of the message a key leaf carries."""
    from simpletrack.wire.generate import json_schemas

    return json_schemas()[f"{SCHEMA_NAMES[leaf]}.schema.json"].encode()


def version() -> str:
    try:
        return importlib.metadata.version("simpletrack-service")
    except importlib.metadata.PackageNotFoundError:  # run from a checkout
        return "unknown"


def split_key(key: str) -> tuple[str, str, str, str] | None:
    """(prefix, vehicle, sensor, leaf) of a ``<prefix>/<vehicle>/<sensor>/<leaf>`` key."""
    parts = key.split("/")
    if len(parts) < 4 or parts[-1] not in LEAVES:
        return None
    return "/".join(parts[:-3]), parts[-3], parts[-2], parts[-1]
