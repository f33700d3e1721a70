"""Detection and track frames as Foxglove 3D scenes (``foxglove.SceneUpdate``): per box a cube
(centre, yaw about +z, size; tracks coloured by state), a text with the track id and class, and
an arrow for the velocity (one second of travel). A detection frame's pose becomes a
``foxglove.FrameTransform`` from the world frame to the sensor's.

A fused vehicle's tracks (``VehicleTrackFrame``, sensor ``@vehicle``) are drawn the same way,
each labelled with its existence too (metadata: ``existence`` and the ``sensors`` that updated
it). A detection frame's extrinsic (sensor->vehicle, a fused vehicle without poses) becomes a
``FrameTransform`` from the vehicle's frame (its fused tracks' ``frame_id``) to the sensor's.

Each update first deletes every entity of its topic stamped before it, so the 3D panel shows
exactly the latest frame's boxes at any replay speed (a lifetime would be judged against
Foxglove's clock, which is not the sensor's). Entity ids are the tracks' fleet-unique ids:
``<vehicle>/<sensor>/<track id>``, ``<vehicle>/@vehicle/<track id>`` for fused tracks
(detections: ``<vehicle>/<sensor>/d<row>``).

Works on the plainly decoded msgpack map: a frame whose columns do not match its count gives no
scene (the raw and JSON channels still hold it)."""

from __future__ import annotations

import math
from typing import Any

import numpy as np
import numpy.typing as npt

from simpletrack.wire.columns import (
    DETECTION_SPECS,
    TRACK_COLUMNS_OF,
    TRACK_SPECS,
    VEHICLE_TRACK_SPECS,
    ColumnSpec,
    view_column,
)
from simpletrack.wire.keys import DETECTIONS, VEHICLE_STREAM
from simpletrack.wire.reasons import STATE_NAMES
from simpletrack.wire.track_ids import global_id

# The service's default world frame (world_frame_id), until a track frame names the real one.
DEFAULT_WORLD = "world"
# Its default frame of a vehicle's fused tracks (fusion.vehicle_frame_id), likewise.
DEFAULT_VEHICLE = "base_link"
# Fill colours as in `simpletrack view`: confirmed green, tentative amber, coasting blue.
STATE_COLORS = {
    0: (0.690, 0.490, 0.071),
    1: (0.180, 0.627, 0.263),
    2: (0.231, 0.365, 0.561),
}
DETECTION_COLOR = (0.85, 0.85, 0.85)
UNKNOWN_COLOR = (0.8, 0.2, 0.8)
ALPHA = 0.5
MIN_SPEED = 0.1  # m/s: slower boxes get no arrow
_DELETE_ALL = 1  # foxglove.SceneEntityDeletionType.ALL


def _time(ns: int) -> dict[str, int]:
    return {"sec": ns // 1_000_000_000, "nsec": ns % 1_000_000_000}


def _xyz(v: list[float]) -> dict[str, float]:
    return {"x": v[0], "y": v[1], "z": v[2]}


def _rgba(rgb: tuple[float, float, float], a: float) -> dict[str, float]:
    return {"r": rgb[0], "g": rgb[1], "b": rgb[2], "a": a}


def yaw_quaternion(yaw: float) -> dict[str, float]:
    return {"x": 0.0, "y": 0.0, "z": math.sin(yaw / 2.0), "w": math.cos(yaw / 2.0)}


def direction_quaternion(v: list[float]) -> dict[str, float]:
    """The rotation taking +x to the direction of v (yaw about z, then pitch about y)."""
    yaw = math.atan2(v[1], v[0])
    pitch = -math.atan2(v[2], math.hypot(v[0], v[1]))
    cy, sy, cp, sp = math.cos(yaw / 2), math.sin(yaw / 2), math.cos(pitch / 2), math.sin(pitch / 2)
    return {"x": -sy * sp, "y": cy * sp, "z": sy * cp, "w": cy * cp}


def matrix_quaternion(m: list[list[float]]) -> dict[str, float]:
    """The unit quaternion of a 3x3 rotation matrix (Shepperd's method: no division by ~0)."""
    trace = m[0][0] + m[1][1] + m[2][2]
    if trace > 0:
        s = 2.0 * math.sqrt(trace + 1.0)
        q = (
            (m[2][1] - m[1][2]) / s,
            (m[0][2] - m[2][0]) / s,
            (m[1][0] - m[0][1]) / s,
            s / 4,
        )
    elif m[0][0] >= m[1][1] and m[0][0] >= m[2][2]:
        s = 2.0 * math.sqrt(max(1.0 + m[0][0] - m[1][1] - m[2][2], 1e-12))
        q = (s / 4, (m[0][1] + m[1][0]) / s, (m[0][2] + m[2][0]) / s, (m[2][1] - m[1][2]) / s)
    elif m[1][1] >= m[2][2]:
        s = 2.0 * math.sqrt(max(1.0 + m[1][1] - m[0][0] - m[2][2], 1e-12))
        q = ((m[0][1] + m[1][0]) / s, s / 4, (m[1][2] + m[2][1]) / s, (m[0][2] - m[2][0]) / s)
    else:
        s = 2.0 * math.sqrt(max(1.0 + m[2][2] - m[0][0] - m[1][1], 1e-12))
        q = ((m[0][2] + m[2][0]) / s, (m[1][2] + m[2][1]) / s, s / 4, (m[1][0] - m[0][1]) / s)
    norm = math.sqrt(sum(c * c for c in q)) or 1.0
    return dict(zip("xyzw", (c / norm for c in q), strict=True))


def _columns(
    table: object, specs: dict[str, ColumnSpec], sensors: int = 1
) -> tuple[int, list[str], dict[str, npt.NDArray[np.generic]]] | None:
    """(count, classes, columns) of a box table, or None when any column is missing (but
    optional) or of the wrong length. A per-sensor column holds ``sensors`` values a row."""
    if not isinstance(table, dict):
        return None
    count, classes = table.get("count"), table.get("classes")
    if type(count) is not int or count < 0 or not isinstance(classes, list):
        return None
    columns = {}
    for name, spec in specs.items():
        buf = table.get(name)
        if buf is None and spec.optional:
            continue
        width = sensors if spec.per_sensor else 1
        if not isinstance(buf, bytes) or len(buf) != count * spec.row_bytes * width:
            return None
        column = view_column(buf, spec)
        columns[name] = column.reshape(count, sensors) if spec.per_sensor else column
    return count, [str(c) for c in classes], columns


def _sensors(value: object) -> list[str] | None:
    if not isinstance(value, list) or not value or not all(isinstance(s, str) for s in value):
        return None
    return value


class SceneConverter:
    def __init__(self) -> None:
        self._world: dict[tuple[str, str], str] = {}
        self._vehicle_frame: dict[str, str] = {}

    def convert(
        self, leaf: str, vehicle: str, sensor: str, frame: dict[str, Any]
    ) -> tuple[dict[str, Any] | None, dict[str, Any] | None]:
        """(SceneUpdate, FrameTransform or None) of a detection, track or fused track frame's
        map (``sensor`` ``@vehicle``: a VehicleTrackFrame)."""
        stamp, frame_id = frame.get("stamp_ns"), frame.get("frame_id")
        if type(stamp) is not int or stamp < 0 or not isinstance(frame_id, str):
            return None, None
        detections = leaf == DETECTIONS
        pose = _pose(frame.get("pose"))
        fused = None
        if sensor == VEHICLE_STREAM:
            fused = _sensors(frame.get("sensors"))
            if fused is None:
                return None, None
            if pose is not None:  # tracked in the world frame: its sensors' poses lead there
                self._world.update({(vehicle, s): frame_id for s in fused})
            else:  # in the vehicle's frame: its sensors' extrinsics lead there
                self._vehicle_frame[vehicle] = frame_id
        elif not detections and pose is not None:
            self._world[(vehicle, sensor)] = frame_id
        specs = (
            DETECTION_SPECS if detections else TRACK_SPECS if fused is None else VEHICLE_TRACK_SPECS
        )
        version = frame.get("schema_version")
        if specs is TRACK_SPECS and type(version) is int and version in TRACK_COLUMNS_OF:
            specs = {c.name: c for c in TRACK_COLUMNS_OF[version]}  # version 1: no ages in s
        table = _columns(
            frame.get("boxes" if detections else "tracks"),
            specs,
            1 if fused is None else len(fused),
        )
        scene = None
        if table is not None:
            entities = _entities(detections, vehicle, sensor, stamp, frame_id, *table, fused)
            deletion = {"timestamp": _time(stamp), "type": _DELETE_ALL, "id": ""}
            scene = {"deletions": [deletion], "entities": entities}
        transform = None
        if detections:
            extrinsic = _pose(frame.get("extrinsic")) if pose is None else None
            parent = (
                self._world.get((vehicle, sensor), DEFAULT_WORLD)
                if pose is not None
                else self._vehicle_frame.get(vehicle, DEFAULT_VEHICLE)
            )
            matrix = pose if pose is not None else extrinsic
            if matrix is not None:
                transform = {
                    "timestamp": _time(stamp),
                    "parent_frame_id": parent,
                    "child_frame_id": frame_id,
                    "translation": _xyz([row[3] for row in matrix[:3]]),
                    "rotation": matrix_quaternion([row[:3] for row in matrix[:3]]),
                }
        return scene, transform


def _pose(value: object) -> list[list[float]] | None:
    if (
        not isinstance(value, list)
        or len(value) != 16
        or not all(type(v) in (int, float) and math.isfinite(v) for v in value)
    ):
        return None
    return [[float(v) for v in value[4 * r : 4 * r + 4]] for r in range(4)]


def _entities(
    detections: bool,
    vehicle: str,
    sensor: str,
    stamp: int,
    frame_id: str,
    count: int,
    classes: list[str],
    cols: dict[str, npt.NDArray[np.generic]],
    fused: list[str] | None = None,
) -> list[dict[str, Any]]:
    """The boxes' entities; ``fused``: a VehicleTrackFrame's sensors (its tracks carry
    ``existence`` and ``sensor_stamp_ns``, one column per sensor)."""
    center, size, yaw = cols["center"].tolist(), cols["size"].tolist(), cols["yaw"].tolist()
    class_index, score = cols["class_index"].tolist(), cols["score"].tolist()
    velocity = cols["velocity"].tolist() if "velocity" in cols else None
    ids = None if detections else cols["id"].tolist()
    states = None if detections else cols["state"].tolist()
    existence = cols["existence"].tolist() if fused is not None else None
    updated = cols["sensor_stamp_ns"].tolist() if fused is not None else None
    out = []
    for i in range(count):
        name = classes[class_index[i]] if 0 <= class_index[i] < len(classes) else "?"
        metadata = [{"key": "class", "value": name}, {"key": "score", "value": f"{score[i]:.3f}"}]
        if ids is None or states is None:
            entity_id, label, rgb = (
                f"{vehicle}/{sensor}/d{i}",
                f"{name} {score[i]:.2f}",
                DETECTION_COLOR,
            )
        else:
            entity_id, label = global_id(vehicle, sensor, ids[i]), f"{ids[i]} {name}"
            rgb = STATE_COLORS.get(states[i], UNKNOWN_COLOR)
            metadata.append({"key": "state", "value": STATE_NAMES.get(states[i], str(states[i]))})
        if existence is not None and updated is not None and fused is not None:
            label += f" p={existence[i]:.2f}"
            by = [s for s, t in zip(fused, updated[i], strict=True) if t >= 0]
            metadata += [
                {"key": "existence", "value": f"{existence[i]:.3f}"},
                {"key": "sensors", "value": ",".join(by)},
            ]
        c, s = center[i], size[i]
        top = {"x": c[0], "y": c[1], "z": c[2] + s[2] / 2 + 0.3}
        arrows = []
        if velocity is not None:
            v = [*velocity[i], 0.0][:3]
            speed = math.sqrt(sum(x * x for x in v))
            if math.isfinite(speed) and speed >= MIN_SPEED:
                arrows.append(
                    {
                        "pose": {"position": _xyz(c), "orientation": direction_quaternion(v)},
                        "shaft_length": speed,
                        "shaft_diameter": 0.1,
                        "head_length": 0.4,
                        "head_diameter": 0.3,
                        "color": _rgba(rgb, 1.0),
                    }
                )
        out.append(
            {
                "timestamp": _time(stamp),
                "frame_id": frame_id,
                "id": entity_id,
                "lifetime": {"sec": 0, "nsec": 0},
                "frame_locked": False,
                "metadata": metadata,
                "arrows": arrows,
                "cubes": [
                    {
                        "pose": {"position": _xyz(c), "orientation": yaw_quaternion(yaw[i])},
                        "size": _xyz(s),
                        "color": _rgba(rgb, ALPHA),
                    }
                ],
                "spheres": [],
                "cylinders": [],
                "lines": [],
                "triangles": [],
                "texts": [
                    {
                        "pose": {"position": top, "orientation": yaw_quaternion(0.0)},
                        "billboard": True,
                        "font_size": 14.0,
                        "scale_invariant": True,
                        "color": _rgba((1.0, 1.0, 1.0), 1.0),
                        "text": label,
                    }
                ],
                "models": [],
            }
        )
    return out
