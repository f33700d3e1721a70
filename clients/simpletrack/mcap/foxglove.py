"""The channels a recording carries for Foxglove next to each raw key (Foxglove decodes no
msgpack): ``<key>/json``, the message as JSON with its box table as one object of numbers per
box, for the Plot and Raw Messages panels (rows.py), and, for detections
and tracks (a fused vehicle's ``@vehicle`` tracks too), ``<key>/scene`` (a
``foxglove.SceneUpdate`` of the boxes) and ``<key>/tf`` (a ``foxglove.FrameTransform`` of a
detection frame's pose, or of its extrinsic). None of these topics ends in a key leaf, so
``replay mcap`` never takes them for detections.

The JSON channels' schema is the wire model's JSON Schema flattened into the subset Foxglove's
JSON Schema reader takes: every property with one ``type`` (no ``$ref``, no ``anyOf`` with
null), the box table's columns replaced by the rows' fields (``rows.twin_schema``). A field
that may be null keeps its non-null type; its value can still be null."""

from __future__ import annotations

import base64
import functools
import importlib.resources
import json
import math
from dataclasses import dataclass
from typing import Any

import msgpack

from simpletrack.mcap.format import schema_data, schema_name
from simpletrack.mcap.rows import twin, twin_schema
from simpletrack.mcap.scene import SceneConverter
from simpletrack.wire.header import MAX_BYTES
from simpletrack.wire.keys import ERRORS

JSON_ENCODING = "json"
JSON_SUFFIX = "/json"
SCENE_SUFFIX = "/scene"
TF_SUFFIX = "/tf"
SCENE_SCHEMA = "foxglove.SceneUpdate"
TF_SCHEMA = "foxglove.FrameTransform"


@dataclass(frozen=True, slots=True)
class Derived:
    """One message for a Foxglove channel: its topic, schema name and JSON bytes."""

    topic: str
    schema: str
    data: bytes


@functools.cache
def foxglove_schema(name: str) -> bytes:
    """The JSON Schema text a Foxglove channel is described by, by schema name (a Foxglove
    schema's, or a wire model's: its JSON Schema flattened, with the box table as rows)."""
    if name in (SCENE_SCHEMA, TF_SCHEMA):
        file = importlib.resources.files("simpletrack.mcap") / "foxglove_schemas"
        return (file / f"{name.removeprefix('foxglove.')}.json").read_bytes()
    return json.dumps(twin_schema(name, flatten(json.loads(schema_data(name)))), indent=2).encode()


def flatten(schema: dict[str, Any]) -> dict[str, Any]:
    """``$ref`` inlined from ``$defs`` and ``anyOf [X, null]`` collapsed to X, all the way down."""
    defs: dict[str, Any] = schema.get("$defs", {})

    def walk(node: Any) -> Any:
        if isinstance(node, list):
            return [walk(n) for n in node]
        if not isinstance(node, dict):
            return node
        node = dict(node)
        ref = node.pop("$ref", None)
        if isinstance(ref, str) and ref.startswith("#/$defs/"):
            node = {**defs[ref.removeprefix("#/$defs/")], **node}
        alternatives = node.get("anyOf")
        if isinstance(alternatives, list):
            real = [a for a in alternatives if a != {"type": "null"}]
            if len(real) == 1 and len(real) < len(alternatives):
                del node["anyOf"]
                node = {**real[0], **node}
                if node.get("default", 0) is None:
                    del node["default"]
        return {k: walk(v) for k, v in node.items() if k != "$defs"}

    out = walk(schema)
    assert isinstance(out, dict)
    out.pop("$id", None)  # a different document: it must not claim the wire schema's id
    return out


_COMPACT: dict[str, Any] = {"ensure_ascii": False, "separators": (",", ":")}


def _bin(value: object) -> str:
    if isinstance(value, bytes):
        return base64.b64encode(value).decode("ascii")
    raise TypeError(type(value).__name__)


def _finite(node: Any) -> Any:
    # JSON has no NaN or infinity: such a value (only in a damaged frame) is shown as null.
    if isinstance(node, float):
        return node if math.isfinite(node) else None
    if isinstance(node, dict):
        return {k: _finite(v) for k, v in node.items()}
    if isinstance(node, list):
        return [_finite(v) for v in node]
    return node


def to_json(obj: object) -> bytes | None:
    """The decoded msgpack value as compact JSON, bins as base64; None when JSON cannot hold it
    (msgpack extension types, non-string keys)."""
    try:
        try:
            text = json.dumps(obj, default=_bin, allow_nan=False, **_COMPACT)
        except ValueError:
            text = json.dumps(_finite(obj), default=_bin, allow_nan=False, **_COMPACT)
    except (TypeError, ValueError):
        return None
    return text.encode()


def unpack(payload: bytes) -> dict[str, Any] | None:
    """The payload's msgpack map, plainly decoded (no validation), or None."""
    if len(payload) > MAX_BYTES:
        return None
    try:
        obj = msgpack.unpackb(payload, raw=False)
    except Exception:  # garbage of any kind: the raw channel still holds it
        return None
    return obj if isinstance(obj, dict) else None


class FoxgloveChannels:
    """What each raw sample adds on the Foxglove channels. Keeps, per sensor, the name of the
    world frame its tracks were last given in (the parent of its detections' transforms)."""

    def __init__(self) -> None:
        self._scenes = SceneConverter()

    def derive(
        self, key: str, leaf: str, vehicle: str, sensor: str, payload: bytes
    ) -> list[Derived]:
        obj = unpack(payload)
        if obj is None:
            return []
        out = []
        name = schema_name(sensor, leaf)
        shown = twin(name, obj)
        text = None if shown is None else to_json(shown)
        if text is not None:
            out.append(Derived(key + JSON_SUFFIX, name, text))
        if leaf == ERRORS:
            return out
        scene, transform = self._scenes.convert(leaf, vehicle, sensor, obj)
        for topic, schema, value in (
            (key + SCENE_SUFFIX, SCENE_SCHEMA, scene),
            (key + TF_SUFFIX, TF_SCHEMA, transform),
        ):
            data = _dumps(value)
            if data is not None:
                out.append(Derived(topic, schema, data))
        return out


def _dumps(value: dict[str, Any] | None) -> bytes | None:
    if value is None:
        return None
    try:  # a NaN box (only in a damaged frame) has no place in a scene
        return json.dumps(value, allow_nan=False, **_COMPACT).encode()
    except ValueError:
        return None
