"""The vehicle view's pieces (docs/VIEW.md, "Vehicle view"): where a fused sensor's boxes and
field of view go, each sensor's colour, and which sensors last updated a fused track.

A fused sensor's boxes are moved the way the service moves them (server/fused.py): by the
frame's pose (sensor -> world) when it has one, the vehicle then being tracked in the world
frame, else by its extrinsic (sensor -> vehicle), the vehicle tracked in its own frame. A
frame of the other kind than the vehicle's is one the service refuses: it is not drawn.

Pure: decoded frames in, JSON-ready dicts out.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np
import numpy.typing as npt

from simpletrack.wire.codec import DecodedDetections
from simpletrack.wire.reasons import SensorCondition

F64 = npt.NDArray[np.float64]

# One colour per fused sensor, in the order of the vehicle's ``sensors``: none of them the
# track states' fills or outlines (green, amber, blue), the velocity's cyan or the background.
SENSOR_COLOURS = ("#ff7bd5", "#b48cff", "#ff9e64", "#e8e36a", "#f85149", "#e6edf3")

# Where a sensor's placement (its field of view's apex and heading) comes from.
MOUNT_DETECTIONS = "detections"  # its latest detection frame's pose or extrinsic
MOUNT_TRACKS = "tracks"  # the pose the vehicle's latest message from that sensor echoes
MOUNT_ASSUMED = "assumed"  # unknown: at the vehicle's origin, facing forward


def _r(v: float, digits: int = 3) -> float:
    return round(float(v), digits)


def sensor_colour(index: int) -> str:
    return SENSOR_COLOURS[index % len(SENSOR_COLOURS)]


def fused_transform(decoded: DecodedDetections, world: bool | None) -> F64 | None:
    """The transform the service applies to a fused sensor's frame: its pose when it has one,
    else its extrinsic. ``world``: whether the vehicle is tracked in the world frame (its
    messages carry a pose; None: not known yet). None when the service refuses the frame:
    no transform, or a pose for a vehicle tracked in its own frame, or an extrinsic alone
    for one tracked in the world frame."""
    if decoded.pose is not None:
        return decoded.pose if world is not False else None
    if decoded.extrinsic is not None and world is not True:
        return decoded.extrinsic
    return None


def skipped_because(decoded: DecodedDetections, world: bool | None) -> str:
    """Why ``fused_transform`` gave None, in a few words for the panel."""
    if decoded.pose is not None:
        return "a pose, but the vehicle is tracked in its own frame: refused by the service"
    if decoded.extrinsic is not None:
        return "no pose, but the vehicle is tracked in the world frame: refused by the service"
    return "neither pose nor extrinsic: refused by the service"


def placement(transform: F64 | Sequence[float]) -> dict[str, float]:
    """A sensor's origin and heading (its x axis) in the tracking frame, from its
    sensor -> tracking frame transform (4x4, or 16 numbers row-major)."""
    t = np.asarray(transform, np.float64).reshape(4, 4)
    return {"x": _r(t[0, 3]), "y": _r(t[1, 3]), "yaw": _r(math.atan2(t[1, 0], t[0, 0]), 4)}


def boxes_json(decoded: DecodedDetections, transform: F64 | None) -> list[dict[str, Any]]:
    """The frame's boxes moved by ``transform`` (None: as they are) as the service moves
    them: centres by the full rotation and translation, yaws by the rotation's heading."""
    b = decoded.boxes
    xyz = b.center.astype(np.float64)
    yaw = b.yaw.astype(np.float64)
    if transform is not None:
        xyz = xyz @ transform[:3, :3].T + transform[:3, 3]
        yaw = yaw + math.atan2(transform[1, 0], transform[0, 0])
    names = b.class_names()
    return [
        {
            "class": names[i],
            "x": _r(xyz[i, 0]),
            "y": _r(xyz[i, 1]),
            "l": _r(b.size[i, 0]),
            "w": _r(b.size[i, 1]),
            "yaw": _r(yaw[i], 4),
            "score": _r(b.score[i]),
        }
        for i in range(len(b))
    ]


def vehicle_pose(decoded: DecodedDetections) -> F64 | None:
    """vehicle -> world from a frame carrying both its pose and its extrinsic."""
    if decoded.pose is None or decoded.extrinsic is None:
        return None
    pose: F64 = decoded.pose @ np.linalg.inv(decoded.extrinsic)
    return pose


def contributors_json(
    sensors: Sequence[str],
    conditions: Sequence[SensorCondition],
    stamps: Sequence[int],
    stamp_ns: int,
    applied: Mapping[str, int],
) -> list[dict[str, Any]]:
    """The sensors that updated a track (``stamps``: its ``sensor_stamp_ns`` row, -1 for
    never), in the vehicle's sensor order, each with the age of its last update at the
    message's ``stamp_ns`` and whether it is **fresh**: the sensor is ``ok`` and its latest
    frame applied (``applied``: sensor -> stamp of the latest message it produced; a sensor
    missing there counts as fresh) updated the track. Not fresh: the sensor updated it
    before and has missed it since (out of view, or not detected), or it is silent or kept
    out."""
    out = []
    for name, condition, stamp in zip(sensors, conditions, stamps, strict=True):
        if stamp < 0:
            continue
        latest = applied.get(name)
        fresh = condition == SensorCondition.OK and (latest is None or stamp >= latest)
        out.append(
            {
                "sensor": name,
                "stamp_ns": int(stamp),
                "age_s": _r((stamp_ns - stamp) * 1e-9, 3),
                "fresh": fresh,
            }
        )
    return out
