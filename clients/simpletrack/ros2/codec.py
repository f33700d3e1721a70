"""CDR serialization of exactly the messages in ``messages.py``, field by field in .msg order.

    objects = decode_detected_objects(payload)      # bytes from ROS 2 -> DetectedObjects
    payload = encode_tracked_objects(tracked)       # TrackedObjects -> bytes for ROS 2

Both directions exist for both top-level types (the tests round-trip them). A payload that is
not a DetectedObjects/TrackedObjects raises ``CdrError`` with what was wrong and where.
"""

from __future__ import annotations

from simpletrack.ros2.cdr import CdrError, CdrReader, CdrWriter
from simpletrack.ros2.messages import (
    COVARIANCE_SIZE,
    UUID,
    UUID_SIZE,
    Accel,
    AccelWithCovariance,
    DetectedObject,
    DetectedObjectKinematics,
    DetectedObjects,
    Header,
    ObjectClassification,
    Point,
    Point32,
    Polygon,
    Pose,
    PoseWithCovariance,
    Quaternion,
    Shape,
    Time,
    TrackedObject,
    TrackedObjectKinematics,
    TrackedObjects,
    Twist,
    TwistWithCovariance,
    Vector3,
)

__all__ = [
    "CdrError",
    "decode_detected_objects",
    "decode_tracked_objects",
    "encode_detected_objects",
    "encode_tracked_objects",
]

# Lower bounds of one element's bytes: a sequence count is checked against them.
_CLASSIFICATION_BYTES = 5
_POINT32_BYTES = 12
_DETECTED_OBJECT_BYTES = 700
_TRACKED_OBJECT_BYTES = 1000


# --- reading -----------------------------------------------------------------------------------
def _time(r: CdrReader) -> Time:
    return Time(r.int32(), r.uint32())


def _header(r: CdrReader) -> Header:
    return Header(_time(r), r.string())


def _vector3(r: CdrReader) -> Vector3:
    return Vector3(r.float64(), r.float64(), r.float64())


def _pose_with_covariance(r: CdrReader) -> PoseWithCovariance:
    position = Point(r.float64(), r.float64(), r.float64())
    orientation = Quaternion(r.float64(), r.float64(), r.float64(), r.float64())
    return PoseWithCovariance(Pose(position, orientation), r.float64s(COVARIANCE_SIZE))


def _twist_with_covariance(r: CdrReader) -> TwistWithCovariance:
    twist = Twist(_vector3(r), _vector3(r))
    return TwistWithCovariance(twist, r.float64s(COVARIANCE_SIZE))


def _accel_with_covariance(r: CdrReader) -> AccelWithCovariance:
    accel = Accel(_vector3(r), _vector3(r))
    return AccelWithCovariance(accel, r.float64s(COVARIANCE_SIZE))


def _classifications(r: CdrReader) -> tuple[ObjectClassification, ...]:
    n = r.count(_CLASSIFICATION_BYTES)
    return tuple(ObjectClassification(r.uint8(), r.float32()) for _ in range(n))


def _shape(r: CdrReader) -> Shape:
    kind = r.uint8()
    n = r.count(_POINT32_BYTES)
    points = tuple(Point32(r.float32(), r.float32(), r.float32()) for _ in range(n))
    return Shape(kind, Polygon(points), _vector3(r))


def _detected_object(r: CdrReader) -> DetectedObject:
    existence = r.float32()
    classification = _classifications(r)
    kinematics = DetectedObjectKinematics(
        pose_with_covariance=_pose_with_covariance(r),
        has_position_covariance=r.boolean(),
        orientation_availability=r.uint8(),
        twist_with_covariance=_twist_with_covariance(r),
        has_twist=r.boolean(),
        has_twist_covariance=r.boolean(),
    )
    return DetectedObject(existence, classification, kinematics, _shape(r))


def _tracked_object(r: CdrReader) -> TrackedObject:
    object_id = UUID(r.octets(UUID_SIZE))
    existence = r.float32()
    classification = _classifications(r)
    kinematics = TrackedObjectKinematics(
        pose_with_covariance=_pose_with_covariance(r),
        twist_with_covariance=_twist_with_covariance(r),
        acceleration_with_covariance=_accel_with_covariance(r),
        orientation_availability=r.uint8(),
        is_stationary=r.boolean(),
    )
    return TrackedObject(object_id, existence, classification, kinematics, _shape(r))


def decode_detected_objects(payload: bytes) -> DetectedObjects:
    r = CdrReader(payload)
    header = _header(r)
    n = r.count(_DETECTED_OBJECT_BYTES)
    objects = tuple(_detected_object(r) for _ in range(n))
    r.finish()
    return DetectedObjects(header, objects)


def decode_tracked_objects(payload: bytes) -> TrackedObjects:
    r = CdrReader(payload)
    header = _header(r)
    n = r.count(_TRACKED_OBJECT_BYTES)
    objects = tuple(_tracked_object(r) for _ in range(n))
    r.finish()
    return TrackedObjects(header, objects)


# --- writing -----------------------------------------------------------------------------------
def _w_header(w: CdrWriter, h: Header) -> None:
    w.int32(h.stamp.sec)
    w.uint32(h.stamp.nanosec)
    w.string(h.frame_id)


def _w_vector3(w: CdrWriter, v: Vector3 | Point) -> None:
    w.float64(v.x)
    w.float64(v.y)
    w.float64(v.z)


def _w_pose_with_covariance(w: CdrWriter, p: PoseWithCovariance) -> None:
    _w_vector3(w, p.pose.position)
    q = p.pose.orientation
    for v in (q.x, q.y, q.z, q.w):
        w.float64(v)
    w.float64s(p.covariance, COVARIANCE_SIZE)


def _w_twist_or_accel(w: CdrWriter, t: Twist | Accel, covariance: tuple[float, ...]) -> None:
    _w_vector3(w, t.linear)
    _w_vector3(w, t.angular)
    w.float64s(covariance, COVARIANCE_SIZE)


def _w_classification(w: CdrWriter, c: ObjectClassification) -> None:
    w.uint8(c.label)
    w.float32(c.probability)


def _w_point32(w: CdrWriter, p: Point32) -> None:
    w.float32(p.x)
    w.float32(p.y)
    w.float32(p.z)


def _w_shape(w: CdrWriter, s: Shape) -> None:
    w.uint8(s.type)
    w.sequence(s.footprint.points, lambda p: _w_point32(w, p))
    _w_vector3(w, s.dimensions)


def _w_detected_object(w: CdrWriter, o: DetectedObject) -> None:
    w.float32(o.existence_probability)
    w.sequence(o.classification, lambda c: _w_classification(w, c))
    k = o.kinematics
    _w_pose_with_covariance(w, k.pose_with_covariance)
    w.boolean(k.has_position_covariance)
    w.uint8(k.orientation_availability)
    t = k.twist_with_covariance
    _w_twist_or_accel(w, t.twist, t.covariance)
    w.boolean(k.has_twist)
    w.boolean(k.has_twist_covariance)
    _w_shape(w, o.shape)


def _w_tracked_object(w: CdrWriter, o: TrackedObject) -> None:
    if len(o.object_id.uuid) != UUID_SIZE:
        raise ValueError(f"object_id has {len(o.object_id.uuid)} bytes, a UUID has 16")
    w.octets(o.object_id.uuid)
    w.float32(o.existence_probability)
    w.sequence(o.classification, lambda c: _w_classification(w, c))
    k = o.kinematics
    _w_pose_with_covariance(w, k.pose_with_covariance)
    t = k.twist_with_covariance
    _w_twist_or_accel(w, t.twist, t.covariance)
    a = k.acceleration_with_covariance
    _w_twist_or_accel(w, a.accel, a.covariance)
    w.uint8(k.orientation_availability)
    w.boolean(k.is_stationary)
    _w_shape(w, o.shape)


def encode_detected_objects(msg: DetectedObjects) -> bytes:
    w = CdrWriter()
    _w_header(w, msg.header)
    w.sequence(msg.objects, lambda o: _w_detected_object(w, o))
    return bytes(w)


def encode_tracked_objects(msg: TrackedObjects) -> bytes:
    w = CdrWriter()
    _w_header(w, msg.header)
    w.sequence(msg.objects, lambda o: _w_tracked_object(w, o))
    return bytes(w)
