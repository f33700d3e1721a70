"""The independent side of the ROS 2 tests: `rosbags` with the .msg files of
clients/simpletrack/ros2/msg registered, and builders of its message objects.

Nothing here imports our CDR code: bytes made here are what a ROS 2 node would send.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import cache
from typing import Any

import numpy as np
from rosbags.typesys import Stores, get_types_from_msg, get_typestore
from rosbags.typesys.store import Typestore

from simpletrack.ros2.typehash import MSG_DIR

DETECTED = "autoware_perception_msgs/msg/DetectedObjects"
TRACKED = "autoware_perception_msgs/msg/TrackedObjects"


@cache
def typestore() -> Typestore:
    store = get_typestore(Stores.EMPTY)
    types: dict[str, Any] = {}
    for path in sorted(MSG_DIR.glob("*/*.msg")):
        types.update(get_types_from_msg(path.read_text(), f"{path.parent.name}/msg/{path.stem}"))
    store.register(types)
    return store


def T(name: str) -> Any:
    pkg, _, msg = name.partition("/")
    return typestore().types[f"{pkg}/msg/{msg}"]


def cov(base: float = 0.0) -> np.ndarray[Any, np.dtype[np.float64]]:
    return np.arange(36, dtype=np.float64) * base


def header(sec: int, nanosec: int, frame_id: str) -> Any:
    return T("std_msgs/Header")(
        stamp=T("builtin_interfaces/Time")(sec=sec, nanosec=nanosec), frame_id=frame_id
    )


def vec(x: float, y: float, z: float) -> Any:
    return T("geometry_msgs/Vector3")(x=x, y=y, z=z)


def pose(x: float, y: float, z: float, yaw: float, covariance: float = 0.0) -> Any:
    q = T("geometry_msgs/Quaternion")(x=0.0, y=0.0, z=math.sin(yaw / 2), w=math.cos(yaw / 2))
    p = T("geometry_msgs/Pose")(position=T("geometry_msgs/Point")(x=x, y=y, z=z), orientation=q)
    return T("geometry_msgs/PoseWithCovariance")(pose=p, covariance=cov(covariance))


def twist(x: float, y: float, z: float = 0.0, covariance: float = 0.0) -> Any:
    t = T("geometry_msgs/Twist")(linear=vec(x, y, z), angular=vec(0.0, 0.0, 0.0))
    return T("geometry_msgs/TwistWithCovariance")(twist=t, covariance=cov(covariance))


def shape(
    l: float,  # noqa: E741 - Autoware's length
    w: float,
    h: float,
    kind: int = 0,
    footprint: tuple[tuple[float, float, float], ...] = (),
) -> Any:
    points = [T("geometry_msgs/Point32")(x=p[0], y=p[1], z=p[2]) for p in footprint]
    return T("autoware_perception_msgs/Shape")(
        type=kind, footprint=T("geometry_msgs/Polygon")(points=points), dimensions=vec(l, w, h)
    )


def classification(*pairs: tuple[int, float]) -> list[Any]:
    return [
        T("autoware_perception_msgs/ObjectClassification")(label=a, probability=p) for a, p in pairs
    ]


@dataclass(frozen=True)
class FixtureBox:
    cls: str
    label: int
    x: float
    y: float
    z: float
    l: float  # noqa: E741
    w: float
    h: float
    yaw: float
    score: float
    vx: float  # world (sensor) frame
    vy: float


# The shared fixture: stamp 1_700_000_000 s exactly, frame "base_link", vehicle "veh-fixture",
# sensor "lidar", seq 7.
FIXTURE = (
    FixtureBox("Car", 1, 10.0, 2.0, 0.8, 4.5, 1.9, 1.6, 0.1, 0.9, 5.0, 0.0),
    FixtureBox("Pedestrian", 7, 6.0, -3.0, 0.9, 0.8, 0.7, 1.8, 1.5, 0.7, 1.0, 0.5),
    FixtureBox("Car", 1, 25.0, 4.0, 0.8, 4.2, 1.8, 1.5, -0.2, 0.6, -3.0, 0.2),
)
FIXTURE_STAMP_S = 1_700_000_000
FIXTURE_FRAME = "base_link"
FIXTURE_VEHICLE, FIXTURE_SENSOR, FIXTURE_SEQ = "veh-fixture", "lidar", 7


def object_frame_twist(b: FixtureBox) -> tuple[float, float]:
    """The object-frame twist (Autoware's convention) whose world velocity is (vx, vy)."""
    c, s = math.cos(b.yaw), math.sin(b.yaw)
    return c * b.vx + s * b.vy, -s * b.vx + c * b.vy


def detected_object(
    b: FixtureBox,
    *,
    existence: float | None = None,
    classes: list[Any] | None = None,
    has_twist: bool = True,
    kind: int = 0,
) -> Any:
    tx, ty = object_frame_twist(b)
    kin = T("autoware_perception_msgs/DetectedObjectKinematics")(
        pose_with_covariance=pose(b.x, b.y, b.z, b.yaw),
        has_position_covariance=False,
        orientation_availability=2,
        twist_with_covariance=twist(tx, ty),
        has_twist=has_twist,
        has_twist_covariance=False,
    )
    return T("autoware_perception_msgs/DetectedObject")(
        existence_probability=b.score if existence is None else existence,
        classification=classification((b.label, 1.0)) if classes is None else classes,
        kinematics=kin,
        shape=shape(b.l, b.w, b.h, kind),
    )


def detected_objects(
    objects: list[Any], sec: int = FIXTURE_STAMP_S, nanosec: int = 0, frame_id: str = FIXTURE_FRAME
) -> Any:
    return T("autoware_perception_msgs/DetectedObjects")(
        header=header(sec, nanosec, frame_id), objects=objects
    )


def serialize(msg: Any, typename: str = DETECTED) -> bytes:
    return bytes(typestore().serialize_cdr(msg, typename))


def deserialize(raw: bytes, typename: str = TRACKED) -> Any:
    return typestore().deserialize_cdr(raw, typename)


def fixture_cdr() -> bytes:
    return serialize(detected_objects([detected_object(b) for b in FIXTURE]))
