"""The ROS 2 messages the bridge reads and writes, as frozen dataclasses, field for field the
definitions in ``msg/`` (autoware_perception_msgs, std_msgs, geometry_msgs,
builtin_interfaces, unique_identifier_msgs; sources in ``msg/SOURCES.md``).

Field names and order are the .msg ones; defaults are ROS 2's (zeros, identity quaternion),
so a message built with only what matters is still complete.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from enum import IntEnum

COVARIANCE_SIZE = 36  # row-major 6x6: x, y, z, rotation about X, Y, Z
ZERO_COVARIANCE: tuple[float, ...] = (0.0,) * COVARIANCE_SIZE
UUID_SIZE = 16


class Label(IntEnum):
    """``ObjectClassification`` label constants."""

    UNKNOWN = 0
    CAR = 1
    TRUCK = 2
    BUS = 3
    TRAILER = 4
    MOTORCYCLE = 5
    BICYCLE = 6
    PEDESTRIAN = 7
    ANIMAL = 8
    HAZARD = 9
    OVER_DRIVABLE = 10
    UNDER_DRIVABLE = 11


class ShapeType(IntEnum):
    """``Shape.type`` constants."""

    BOUNDING_BOX = 0  # dimensions x = length, y = width, z = height
    CYLINDER = 1  # dimensions x = y = diameter, z = height
    POLYGON = 2  # footprint polygon, dimensions.z = height


class OrientationAvailability(IntEnum):
    """``DetectedObjectKinematics``/``TrackedObjectKinematics`` orientation constants."""

    UNAVAILABLE = 0
    SIGN_UNKNOWN = 1
    AVAILABLE = 2


# --- builtin_interfaces, std_msgs, unique_identifier_msgs -----------------------------------
@dataclass(frozen=True, slots=True)
class Time:
    sec: int = 0  # int32
    nanosec: int = 0  # uint32, [0, 1e9)


@dataclass(frozen=True, slots=True)
class Header:
    stamp: Time = field(default_factory=Time)
    frame_id: str = ""


@dataclass(frozen=True, slots=True)
class UUID:
    uuid: bytes = bytes(UUID_SIZE)  # uint8[16]


# --- geometry_msgs ---------------------------------------------------------------------------
@dataclass(frozen=True, slots=True)
class Point:
    x: float = 0.0
    y: float = 0.0
    z: float = 0.0


@dataclass(frozen=True, slots=True)
class Point32:
    x: float = 0.0  # float32
    y: float = 0.0
    z: float = 0.0


@dataclass(frozen=True, slots=True)
class Vector3:
    x: float = 0.0
    y: float = 0.0
    z: float = 0.0


@dataclass(frozen=True, slots=True)
class Quaternion:
    x: float = 0.0
    y: float = 0.0
    z: float = 0.0
    w: float = 1.0


@dataclass(frozen=True, slots=True)
class Polygon:
    points: tuple[Point32, ...] = ()


@dataclass(frozen=True, slots=True)
class Pose:
    position: Point = field(default_factory=Point)
    orientation: Quaternion = field(default_factory=Quaternion)


@dataclass(frozen=True, slots=True)
class PoseWithCovariance:
    pose: Pose = field(default_factory=Pose)
    covariance: tuple[float, ...] = ZERO_COVARIANCE  # float64[36]


@dataclass(frozen=True, slots=True)
class Twist:
    linear: Vector3 = field(default_factory=Vector3)
    angular: Vector3 = field(default_factory=Vector3)


@dataclass(frozen=True, slots=True)
class TwistWithCovariance:
    twist: Twist = field(default_factory=Twist)
    covariance: tuple[float, ...] = ZERO_COVARIANCE


@dataclass(frozen=True, slots=True)
class Accel:
    linear: Vector3 = field(default_factory=Vector3)
    angular: Vector3 = field(default_factory=Vector3)


@dataclass(frozen=True, slots=True)
class AccelWithCovariance:
    accel: Accel = field(default_factory=Accel)
    covariance: tuple[float, ...] = ZERO_COVARIANCE


# --- autoware_perception_msgs ----------------------------------------------------------------
@dataclass(frozen=True, slots=True)
class ObjectClassification:
    label: int = Label.UNKNOWN  # uint8, a Label
    probability: float = 0.0  # float32, [0, 1]


@dataclass(frozen=True, slots=True)
class Shape:
    type: int = ShapeType.BOUNDING_BOX  # uint8, a ShapeType
    footprint: Polygon = field(default_factory=Polygon)
    dimensions: Vector3 = field(default_factory=Vector3)


@dataclass(frozen=True, slots=True)
class DetectedObjectKinematics:
    pose_with_covariance: PoseWithCovariance = field(default_factory=PoseWithCovariance)
    has_position_covariance: bool = False
    orientation_availability: int = OrientationAvailability.UNAVAILABLE  # uint8
    twist_with_covariance: TwistWithCovariance = field(default_factory=TwistWithCovariance)
    has_twist: bool = False
    has_twist_covariance: bool = False


@dataclass(frozen=True, slots=True)
class DetectedObject:
    existence_probability: float = 0.0  # float32
    classification: tuple[ObjectClassification, ...] = ()
    kinematics: DetectedObjectKinematics = field(default_factory=DetectedObjectKinematics)
    shape: Shape = field(default_factory=Shape)


@dataclass(frozen=True, slots=True)
class DetectedObjects:
    header: Header = field(default_factory=Header)
    objects: tuple[DetectedObject, ...] = ()


@dataclass(frozen=True, slots=True)
class TrackedObjectKinematics:
    pose_with_covariance: PoseWithCovariance = field(default_factory=PoseWithCovariance)
    twist_with_covariance: TwistWithCovariance = field(default_factory=TwistWithCovariance)
    acceleration_with_covariance: AccelWithCovariance = field(default_factory=AccelWithCovariance)
    orientation_availability: int = OrientationAvailability.UNAVAILABLE  # uint8
    is_stationary: bool = False


@dataclass(frozen=True, slots=True)
class TrackedObject:
    object_id: UUID = field(default_factory=UUID)
    existence_probability: float = 0.0  # float32
    classification: tuple[ObjectClassification, ...] = ()
    kinematics: TrackedObjectKinematics = field(default_factory=TrackedObjectKinematics)
    shape: Shape = field(default_factory=Shape)


@dataclass(frozen=True, slots=True)
class TrackedObjects:
    header: Header = field(default_factory=Header)
    objects: tuple[TrackedObject, ...] = ()


DETECTED_OBJECTS = "autoware_perception_msgs/msg/DetectedObjects"
TRACKED_OBJECTS = "autoware_perception_msgs/msg/TrackedObjects"
