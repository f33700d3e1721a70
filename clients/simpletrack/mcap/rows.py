"""The JSON twins' layout (``<key>/json``): a message as JSON with its box table (a detection
frame's ``boxes``, a track frame's or a fused vehicle's ``tracks``) as one object per box, every
value a JSON number or string, so that Foxglove's Plot panel charts any of them:

    fleet/veh01/lidar/tracks/json.tracks[:]{id==7}.x          # track 7's x over time
    fleet/veh01/lidar/tracks/json.count                       # how many tracks
    "fleet/veh01/@vehicle/tracks/json".tracks[:]{id==3}.existence   # quoted: '@' in the topic

A row's fields, in column order (a column the message does not carry is left out):

    id                         the track id (tracks)
    class, class_index         the class name (``classes[class_index]``, ``?`` outside it), its index
    x, y, z                    ``center``, metres, in the message's ``frame_id``
    length, width, height      ``size``, metres
    yaw                        radians about +z
    score                      the detector's or the tracker's score
    vx, vy[, vz], speed        ``velocity`` (m/s) and its norm
    state, state_name          the state code (0 tentative, 1 confirmed, 2 coasting) and its name
    hits, age, time_since_update, age_s, time_since_update_s, existence
    covariance                 the wire's 21 values (upper triangle of the 6x6 over x, y, z, vx,
                               vy, vz), when the message has it
    sensor_stamp_ns            a fused track's: one stamp per entry of the message's ``sensors``
                               (its last update by that sensor, -1: never)

A column that a later schema adds and this module does not know comes under its own name: a
number, or a list of numbers. Next to the rows the twin has ``count`` (the number of rows) and
``classes`` (the message's class table) at its top level; every other field of the message is
as it travelled (bins, if any, as base64). Values are the wire's: a float32 column's as its
shortest decimal (0.8, not 0.800000011920929: read back as a float32, the very value sent),
float64 and integers exactly. A message whose table's columns do not match its count has no twin (its
raw channel still holds it)."""

from __future__ import annotations

from typing import Any

import numpy as np
import numpy.typing as npt

from simpletrack.mcap.scene import _columns, _sensors
from simpletrack.wire.columns import (
    DETECTION_SPECS,
    TRACK_COLUMNS_OF,
    TRACK_SPECS,
    VEHICLE_TRACK_SPECS,
    ColumnSpec,
)
from simpletrack.wire.reasons import STATE_NAMES

# The wire model of each message with a box table, and the table's field name.
TABLES = {"DetectionFrame": "boxes", "TrackFrame": "tracks", "VehicleTrackFrame": "tracks"}
_SPECS = {
    "DetectionFrame": DETECTION_SPECS,
    "TrackFrame": TRACK_SPECS,
    "VehicleTrackFrame": VEHICLE_TRACK_SPECS,
}
# Columns of several values a row that become fields of their own.
_SPLIT = {
    "center": ("x", "y", "z"),
    "size": ("length", "width", "height"),
    "velocity": ("vx", "vy", "vz"),
}
_UNKNOWN_CLASS = "?"


def _short(col: npt.NDArray[np.float32]) -> npt.NDArray[np.float64]:
    """Each float32 as the float64 of its shortest decimal (6 to 9 significant digits, the
    fewest that read back as the same float32: what numpy prints), vectorised: ~0.2 ms for a
    100-track frame's covariances, where printing each value took ~1 ms. Zero, NaN and
    infinity stay as they are."""
    v = col.astype(np.float64)
    out = v.copy()
    todo = np.isfinite(v) & (v != 0)
    exponent = np.floor(np.log10(np.abs(np.where(todo, v, 1.0))))
    for digits in (6, 7, 8, 9):
        k = digits - 1 - exponent  # decimal places kept; a power of ten is exact up to 1e22
        up = np.where(k >= 0, 10.0 ** np.abs(k), 1.0)
        down = np.where(k < 0, 10.0 ** np.abs(k), 1.0)
        rounded = np.round(v * up / down) / up * down
        ok = todo & (rounded.astype(np.float32) == col)
        out[ok] = rounded[ok]
        todo &= ~ok
    return out


def _plain(col: npt.NDArray[np.generic]) -> npt.NDArray[np.generic]:
    """The column as the values its JSON gives: float32s as their shortest decimals."""
    return _short(col.astype(np.float32)) if col.dtype == np.float32 else col


def _tolist(col: npt.NDArray[np.generic]) -> list[Any]:
    values: list[Any] = col.tolist()
    return values


def _json_type(spec: ColumnSpec) -> str:
    return "integer" if np.dtype(spec.dtype).kind in "iu" else "number"


def _specs(schema: str, obj: dict[str, Any]) -> dict[str, ColumnSpec]:
    if schema == "TrackFrame":
        version = obj.get("schema_version")
        if type(version) is int and version in TRACK_COLUMNS_OF:  # version 1: no ages in s
            return {c.name: c for c in TRACK_COLUMNS_OF[version]}
    return _SPECS[schema]


def twin(schema: str, obj: dict[str, Any]) -> dict[str, Any] | None:
    """The JSON twin of a plainly decoded message (``schema``: its wire model's name); the
    message itself when it has no box table (a FrameError); None when its table is damaged."""
    table = TABLES.get(schema)
    if table is None:
        return obj
    sensors = 1
    if schema == "VehicleTrackFrame":
        fused = _sensors(obj.get("sensors"))
        if fused is None:
            return None
        sensors = len(fused)
    columns = _columns(obj.get(table), _specs(schema, obj), sensors)
    if columns is None:
        return None
    count, classes, cols = columns
    names: list[str] = []
    values: list[list[Any]] = []
    for name, col in cols.items():
        if name == "class_index":
            index = col.tolist()
            names += ["class", "class_index"]
            values += [
                [classes[i] if 0 <= i < len(classes) else _UNKNOWN_CLASS for i in index],
                index,
            ]
        elif name == "state":
            codes = col.tolist()
            names += ["state", "state_name"]
            values += [codes, [STATE_NAMES.get(c, str(c)) for c in codes]]
        elif name in _SPLIT and col.ndim == 2:
            width = col.shape[1]
            if name == "velocity":  # its norm, a float32 like the column
                speed = np.sqrt((col.astype(np.float64) ** 2).sum(axis=1)).astype(col.dtype)
                col = np.column_stack([col, speed])
            plain = _plain(col)
            names += _SPLIT[name][:width]
            values += [_tolist(plain[:, j]) for j in range(width)]
            if name == "velocity":
                names.append("speed")
                values.append(_tolist(plain[:, width]))
        else:  # one value a row, or a list of them (covariance, sensor_stamp_ns)
            names.append(name)
            values.append(_tolist(_plain(col)))
    rows = [dict(zip(names, row, strict=True)) for row in zip(*values, strict=True)]
    out = {k: v for k, v in obj.items() if k != table}
    out.update({table: rows, "count": count, "classes": classes})
    return out


def _row_properties(schema: str, table: dict[str, Any]) -> dict[str, Any]:
    """The JSON Schema of a row's fields, described by the wire's column descriptions."""
    described = table.get("properties", {})

    def doc(column: str) -> str:
        text = described.get(column, {}).get("description", "")
        return f"{column}: {text}" if text else column

    props: dict[str, Any] = {}
    for name, spec in _SPECS[schema].items():
        kind = _json_type(spec)
        if name == "class_index":
            props["class"] = {"type": "string", "description": "classes[class_index]"}
            props["class_index"] = {"type": kind, "description": doc(name)}
        elif name == "state":
            props["state"] = {"type": kind, "description": doc(name)}
            props["state_name"] = {
                "type": "string",
                "description": ", ".join(STATE_NAMES.values()),
            }
        elif name in _SPLIT and spec.width > 1:
            for field in _SPLIT[name][: spec.width]:
                props[field] = {"type": kind, "description": doc(name)}
            if name == "velocity":
                props["speed"] = {"type": "number", "description": "norm of velocity, m/s"}
        elif spec.width > 1 or spec.per_sensor:
            props[name] = {"type": "array", "items": {"type": kind}, "description": doc(name)}
        else:
            props[name] = {"type": kind, "description": doc(name)}
    return props


def twin_schema(schema: str, flat: dict[str, Any]) -> dict[str, Any]:
    """The twin's JSON Schema from the wire model's flattened one: the table as an array of
    row objects, ``count`` and ``classes`` beside it."""
    table = TABLES.get(schema)
    if table is None:
        return flat
    props = dict(flat["properties"])
    wire_table = props[table]
    classes = wire_table.get("properties", {}).get("classes", {"type": "array"})
    props[table] = {
        "type": "array",
        "description": f"{wire_table.get('description', table)} One object per row.",
        "items": {"type": "object", "properties": _row_properties(schema, wire_table)},
    }
    props["count"] = {"type": "integer", "minimum": 0, "description": f"rows of {table}"}
    props["classes"] = {**classes, "description": f"class table of {table}"}
    return {**flat, "properties": props, "required": [*flat.get("required", []), "count"]}
