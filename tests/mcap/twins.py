"""What a ``<key>/json`` twin must hold, checked against the wire's own decoder (not the twin's
code): every field of the message as it travelled, and its box table as one object of plain
JSON numbers per box, equal to the decoded columns."""

from __future__ import annotations

import math
from typing import Any

import msgpack
import numpy as np

from simpletrack.wire import (
    Rejection,
    TrackArrays,
    decode_detection_frame,
    decode_track_frame,
    decode_vehicle_track_frame,
)
from simpletrack.wire.columns import BoxArrays

STATES = {0: "tentative", 1: "confirmed", 2: "coasting"}


def _decoded(schema: str, raw: bytes) -> BoxArrays | TrackArrays:
    if schema == "DetectionFrame":
        detections = decode_detection_frame(raw)
        assert not isinstance(detections, Rejection), detections
        return detections.boxes
    tracks = decode_track_frame(raw) if schema == "TrackFrame" else decode_vehicle_track_frame(raw)
    assert not isinstance(tracks, Rejection), tracks
    return tracks[1]


def _f32(values: Any) -> list[float]:
    return np.float32(values).tolist()  # type: ignore[no-any-return]


def check_twin(value: dict[str, Any], raw: bytes, schema: str) -> None:
    table = "boxes" if schema == "DetectionFrame" else "tracks"
    obj = msgpack.unpackb(raw)
    assert {k: v for k, v in value.items() if k not in (table, "count", "classes")} == {
        k: v for k, v in obj.items() if k != table
    }
    arrays = _decoded(schema, raw)
    rows = value[table]
    assert value["count"] == len(rows) == len(arrays)
    assert value["classes"] == list(arrays.classes)
    velocity = arrays.velocity
    for i, row in enumerate(rows):
        for name, v in row.items():  # plottable: numbers, lists of numbers, two names
            if name in ("class", "state_name"):
                assert isinstance(v, str), (name, v)
            elif isinstance(v, list):
                assert all(type(x) in (int, float) for x in v), (name, v)
            else:
                assert type(v) in (int, float), (name, v)
        assert row["class"] == arrays.classes[arrays.class_index[i]]
        assert row["class_index"] == int(arrays.class_index[i])
        # A float32 column as its shortest decimal: the float32 read back is the one sent.
        assert _f32([row["x"], row["y"], row["z"]]) == arrays.center[i].tolist()
        assert _f32([row["length"], row["width"], row["height"]]) == arrays.size[i].tolist()
        assert _f32(row["yaw"]) == float(arrays.yaw[i])
        assert row["score"] == float(arrays.score[i])
        if velocity is None:
            assert "vx" not in row and "speed" not in row
        else:
            axes = ["vx", "vy", "vz"][: velocity.shape[1]]
            assert _f32([row[a] for a in axes]) == velocity[i].tolist()
            speed = math.sqrt(sum(float(v) ** 2 for v in velocity[i]))
            assert math.isclose(row["speed"], speed, rel_tol=1e-6, abs_tol=1e-9)
        if isinstance(arrays, TrackArrays):
            assert row["id"] == int(arrays.id[i])
            assert row["state"] == int(arrays.state[i])
            assert row["state_name"] == STATES[int(arrays.state[i])]
            for name in ("hits", "age", "time_since_update"):
                assert row[name] == int(getattr(arrays, name)[i]), name
            for name in ("age_s", "time_since_update_s", "existence"):
                column = getattr(arrays, name)
                assert row.get(name) == (None if column is None else float(column[i])), name
            if arrays.covariance is None:
                assert "covariance" not in row
            else:
                assert _f32(row["covariance"]) == arrays.covariance[i].tolist()
            stamps = arrays.sensor_stamp_ns
            assert row.get("sensor_stamp_ns") == (None if stamps is None else stamps[i].tolist())
