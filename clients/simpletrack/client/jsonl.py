"""Received tracks as JSON lines: one object per ``TrackFrame``, for anything that reads JSON
(``simpletrack record --format jsonl``, ``simpletrack plot``). Light: the wire and numpy only.

::

    {"vehicle": "veh00", "sensor": "lidar", "seq": 12, "stamp_ns": ..., "frame_id": "world",
     "received_ns": ..., "published_ns": ..., "tracks": [
        {"id": 3, "cls": "vehicle", "box": [x, y, z, yaw, l, w, h], "score": 0.91,
         "velocity": [vx, vy, vz], "state": "confirmed", "hits": 9, "age": 11,
         "time_since_update": 0}, ...]}
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import IO, Any

import numpy as np
import numpy.typing as npt

from simpletrack.wire import TrackArrays, TrackFrame
from simpletrack.wire.reasons import STATE_NAMES


def rounded(a: npt.NDArray[Any], digits: int = 4) -> list[Any]:
    return np.round(a.astype(np.float64), digits).tolist()  # type: ignore[no-any-return]


def message_to_json(f: TrackFrame, t: TrackArrays) -> dict[str, Any]:
    """One received track frame (header and columns) as a JSON lines object."""
    box = np.column_stack([t.center, t.yaw, t.size])  # x, y, z, yaw, l, w, h
    tracks = [
        {
            "id": i,
            "cls": c,
            "box": b,
            "score": s,
            "velocity": v,
            "state": STATE_NAMES.get(st, str(st)),
            "hits": h,
            "age": a,
            "time_since_update": tsu,
        }
        for i, c, b, s, v, st, h, a, tsu in zip(
            t.id.tolist(),
            [t.classes[i] for i in t.class_index.tolist()],
            rounded(box),
            rounded(t.score),
            rounded(t.velocity),
            t.state.tolist(),
            t.hits.tolist(),
            t.age.tolist(),
            t.time_since_update.tolist(),
            strict=True,
        )
    ]
    return {
        "vehicle": f.vehicle,
        "sensor": f.sensor,
        "seq": f.seq,
        "stamp_ns": f.stamp_ns,
        "frame_id": f.frame_id,
        "received_ns": f.received_ns,
        "published_ns": f.published_ns,
        "tracks": tracks,
    }


class JsonlWriter:
    """Appends one JSON object per line; flushes every line (a crash loses nothing)."""

    def __init__(self, path: Path) -> None:
        path.parent.mkdir(parents=True, exist_ok=True)
        self.path = path
        self._file: IO[str] = path.open("w", encoding="utf-8")
        self.lines = 0

    def write(self, obj: dict[str, Any]) -> None:
        self._file.write(json.dumps(obj, separators=(",", ":")) + "\n")
        self._file.flush()
        self.lines += 1

    def close(self) -> None:
        self._file.close()
