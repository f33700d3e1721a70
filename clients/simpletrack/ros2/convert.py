"""Autoware DetectedObjects -> the service's detection columns (and back, for recordings:
``boxes_to_detected_objects``); the service's tracks -> Autoware TrackedObjects.

Detections, object by object:
    class     the classification with the highest probability (the first of equals), through
              the label map; an object whose label maps to no class is left out ("unknown_label")
    score     ``existence_probability``; where a detector leaves it 0 (many Autoware detectors
              do not estimate existence) the best classification's probability instead, so
              that the tracker's score thresholds see a real confidence (``ScoreSource``).
              The float32 is widened through its shortest decimal form (0.9f -> 0.9)
    box       pose position -> centre; orientation quaternion -> yaw about +z; shape
              BOUNDING_BOX dimensions x, y, z -> length, width, height. Other shapes (cylinder,
              polygon) are left out ("not_a_box"), as are objects without any classification
              ("no_classification")
    velocity  Autoware's twist is in the object's own frame (x along its heading): linear x/y
              are rotated by the yaw into the frame of the positions. Sent only when every
              object of the frame has ``has_twist`` (the column is all or nothing)
    stamp     header.stamp as ``sec * 1e9 + nanosec`` ns; frame_id is header.frame_id
Tracks, one TrackedObject each:
    object_id     ``uuid5(NAMESPACE_URL, "simpletrack:" + global id)``, the global id being
                  ``<vehicle>/<sensor>/<track id>`` (schemas/README.md, "Track identity"):
                  one UUID per track of the fleet, for its whole life, never reused. A
                  vehicle's fused track (VehicleTrackFrame) has the global id
                  ``<vehicle>/@vehicle/<track id>``, the same rule: no sensor is named
                  ``@vehicle``, so a fused track's UUID is never a sensor track's
    existence     the fused track's ``existence`` (the posterior that it is a real object)
                  where the columns carry one (a VehicleTrackFrame), else the track score
    class         one classification: the track's class through the label map (the first
                  label mapped to it; UNKNOWN if none) with probability 1.0, since a
                  track's class is fixed when it is born
    kinematics    pose from the box centre and yaw (orientation AVAILABLE); twist linear from
                  the track velocity rotated into the object's frame (z unchanged), angular 0;
                  acceleration 0; is_stationary false. Covariances, from a version-2 frame
                  with the filter's: the pose's x, y, z block (in the header's frame) and the
                  twist's linear block (turned into the object's frame, like the twist);
                  orientation and angular rows stay 0, as does everything from a frame
                  without covariance (version 1, or motion=cv): zero means "not given"
    shape         BOUNDING_BOX with the track's size, no footprint
"""

from __future__ import annotations

import math
import uuid
from collections import Counter
from dataclasses import dataclass, field, replace
from enum import StrEnum

import numpy as np
import numpy.typing as npt

from simpletrack.ros2.labels import LabelMap
from simpletrack.ros2.messages import (
    UUID,
    DetectedObject,
    DetectedObjectKinematics,
    DetectedObjects,
    Header,
    ObjectClassification,
    OrientationAvailability,
    Point,
    Pose,
    PoseWithCovariance,
    Quaternion,
    Shape,
    ShapeType,
    Time,
    TrackedObject,
    TrackedObjectKinematics,
    TrackedObjects,
    Twist,
    TwistWithCovariance,
    Vector3,
)
from simpletrack.wire import BoxArrays, TrackArrays
from simpletrack.wire.track_ids import global_id

NS_PER_S = 1_000_000_000


class ScoreSource(StrEnum):
    EXISTENCE = "existence"  # existence_probability, the best class probability where it is 0
    CLASSIFICATION = "classification"  # the best classification's probability


class Skip(StrEnum):
    """Why an object was left out of its frame."""

    NO_CLASSIFICATION = "no_classification"
    NOT_A_BOX = "not_a_box"
    UNKNOWN_LABEL = "unknown_label"


@dataclass
class Converted:
    """One DetectedObjects as the service's columns, with what was left out."""

    boxes: BoxArrays
    stamp_ns: int
    frame_id: str
    skipped: Counter[Skip] = field(default_factory=Counter)
    unknown_labels: Counter[int] = field(default_factory=Counter)


def yaw_of(q: Quaternion) -> float:
    """Rotation about +z of a quaternion (the heading of a box lying on the ground)."""
    return math.atan2(2.0 * (q.w * q.z + q.x * q.y), 1.0 - 2.0 * (q.y * q.y + q.z * q.z))


def quaternion_of(yaw: float) -> Quaternion:
    return Quaternion(0.0, 0.0, math.sin(yaw / 2.0), math.cos(yaw / 2.0))


def rotate(x: float, y: float, angle: float) -> tuple[float, float]:
    c, s = math.cos(angle), math.sin(angle)
    return c * x - s * y, s * x + c * y


def widen(value: float) -> float:
    """A float32 as the float64 of its shortest decimal form: 0.9f (0.89999997615...) is 0.9,
    so that score thresholds written in decimal compare as written."""
    return float(np.format_float_positional(np.float32(value), unique=True, trim="-"))


def stamp_ns_of(t: Time) -> int:
    return t.sec * NS_PER_S + t.nanosec


def time_of(stamp_ns: int) -> Time:
    sec, nanosec = divmod(stamp_ns, NS_PER_S)
    return Time(sec, nanosec)


def best_classification(obj: DetectedObject) -> ObjectClassification | None:
    best = None
    for c in obj.classification:
        if best is None or c.probability > best.probability:
            best = c
    return best


def detections_to_boxes(
    msg: DetectedObjects,
    labels: LabelMap,
    classes: tuple[str, ...],
    score: ScoreSource = ScoreSource.EXISTENCE,
) -> Converted:
    """The frame's boxes; class codes index ``classes`` (the service's class table)."""
    out = Converted(_empty(classes), stamp_ns_of(msg.header.stamp), msg.header.frame_id)
    rows: list[tuple[int, tuple[float, ...], float, float]] = []
    twists: list[tuple[float, float] | None] = []
    for obj in msg.objects:
        best = best_classification(obj)
        if best is None:
            out.skipped[Skip.NO_CLASSIFICATION] += 1
            continue
        if obj.shape.type != ShapeType.BOUNDING_BOX:
            out.skipped[Skip.NOT_A_BOX] += 1
            continue
        cls = labels.class_of(best.label)
        if cls is None or cls not in classes:
            out.skipped[Skip.UNKNOWN_LABEL] += 1
            out.unknown_labels[best.label] += 1
            continue
        pose = obj.kinematics.pose_with_covariance.pose
        yaw = yaw_of(pose.orientation)
        p, d = pose.position, obj.shape.dimensions
        value = best.probability
        if score is ScoreSource.EXISTENCE and obj.existence_probability > 0:
            value = obj.existence_probability
        rows.append((classes.index(cls), (p.x, p.y, p.z, d.x, d.y, d.z), yaw, widen(value)))
        lin = obj.kinematics.twist_with_covariance.twist.linear
        twists.append(rotate(lin.x, lin.y, yaw) if obj.kinematics.has_twist else None)
    if not rows:
        return out
    n = len(rows)
    geometry = np.array([r[1] for r in rows], dtype=np.float64)
    velocity = None
    if all(t is not None for t in twists):
        velocity = np.array(twists, dtype=np.float32).reshape(n, 2)
    out.boxes = BoxArrays(
        classes=classes,
        class_index=np.array([r[0] for r in rows], dtype=np.int32),
        center=geometry[:, 0:3].astype(np.float32),
        size=geometry[:, 3:6].astype(np.float32),
        yaw=np.array([r[2] for r in rows], dtype=np.float32),
        score=np.array([r[3] for r in rows], dtype=np.float64),
        velocity=velocity,
    )
    return out


def boxes_to_detected_objects(
    boxes: BoxArrays, *, stamp_ns: int, frame_id: str, labels: LabelMap
) -> DetectedObjects:
    """A detection frame as Autoware DetectedObjects, the inverse of the bridge's
    ``detections_to_boxes``: per box one classification (its class through ``labels``,
    probability the score), existence probability the score, pose from the centre and yaw
    (orientation AVAILABLE), the velocity as the twist in the object's frame (``has_twist``
    when the frame has velocities), a BOUNDING_BOX of the size."""
    names = boxes.class_names()
    velocity = boxes.velocity.tolist() if boxes.velocity is not None else None
    objects = []
    for i in range(len(boxes)):
        cx, cy, cz = (float(v) for v in boxes.center[i])
        length, width, height = (float(v) for v in boxes.size[i])
        yaw, score = float(boxes.yaw[i]), float(boxes.score[i])
        twist = TwistWithCovariance()
        if velocity is not None:
            tx, ty = rotate(velocity[i][0], velocity[i][1], -yaw)
            twist = TwistWithCovariance(Twist(linear=Vector3(tx, ty, 0.0)))
        objects.append(
            DetectedObject(
                existence_probability=score,
                classification=(ObjectClassification(labels.label_of(names[i]), score),),
                kinematics=DetectedObjectKinematics(
                    pose_with_covariance=PoseWithCovariance(
                        Pose(Point(cx, cy, cz), quaternion_of(yaw))
                    ),
                    orientation_availability=OrientationAvailability.AVAILABLE,
                    twist_with_covariance=twist,
                    has_twist=velocity is not None,
                ),
                shape=Shape(ShapeType.BOUNDING_BOX, dimensions=Vector3(length, width, height)),
            )
        )
    return DetectedObjects(Header(time_of(stamp_ns), frame_id), tuple(objects))


def _empty(classes: tuple[str, ...]) -> BoxArrays:
    return BoxArrays(
        classes=classes,
        class_index=np.zeros(0, np.int32),
        center=np.zeros((0, 3), np.float32),
        size=np.zeros((0, 3), np.float32),
        yaw=np.zeros(0, np.float32),
        score=np.zeros(0, np.float64),
    )


def object_uuid(vehicle: str, sensor: str, track_id: int) -> bytes:
    """The 16 bytes of ``uuid5(NAMESPACE_URL, "simpletrack:<vehicle>/<sensor>/<id>")``;
    ``sensor`` is ``@vehicle`` for a vehicle's fused tracks."""
    return uuid.uuid5(
        uuid.NAMESPACE_URL, "simpletrack:" + global_id(vehicle, sensor, track_id)
    ).bytes


def _ros_covariances(
    tracks: TrackArrays,
) -> tuple[npt.NDArray[np.float64], npt.NDArray[np.float64]] | None:
    """Each track's pose and twist covariance (N, 36), ROS order (x, y, z, rx, ry, rz)."""
    cov = tracks.covariance_matrices()
    if cov is None:
        return None
    n = len(tracks)
    yaw = tracks.yaw.astype(np.float64)
    c, s = np.cos(-yaw), np.sin(-yaw)
    rot = np.zeros((n, 3, 3))
    rot[:, 0, 0], rot[:, 0, 1], rot[:, 1, 0], rot[:, 1, 1] = c, -s, s, c
    rot[:, 2, 2] = 1.0
    pose = np.zeros((n, 6, 6))
    pose[:, :3, :3] = cov[:, :3, :3]
    twist = np.zeros((n, 6, 6))
    twist[:, :3, :3] = rot @ cov[:, 3:, 3:] @ rot.transpose(0, 2, 1)
    return pose.reshape(n, 36), twist.reshape(n, 36)


def tracks_to_tracked_objects(
    tracks: TrackArrays,
    *,
    vehicle: str,
    sensor: str,
    stamp_ns: int,
    frame_id: str,
    labels: LabelMap,
) -> TrackedObjects:
    """One TrackedObject per track; ``sensor`` is the stream's name (``@vehicle`` for a
    vehicle's fused tracks, whose ``existence`` column becomes the existence probability)."""
    names = tracks.classes
    existence = tracks.score if tracks.existence is None else tracks.existence
    objects = []
    covariances = _ros_covariances(tracks)
    for i in range(len(tracks)):
        cx, cy, cz = (float(v) for v in tracks.center[i])
        length, width, height = (float(v) for v in tracks.size[i])
        yaw = float(tracks.yaw[i])
        vx, vy, vz = (float(v) for v in tracks.velocity[i])
        tx, ty = rotate(vx, vy, -yaw)
        pose = PoseWithCovariance(Pose(Point(cx, cy, cz), quaternion_of(yaw)))
        twist = TwistWithCovariance(Twist(linear=Vector3(tx, ty, vz)))
        if covariances is not None:
            pose = replace(pose, covariance=tuple(covariances[0][i].tolist()))
            twist = replace(twist, covariance=tuple(covariances[1][i].tolist()))
        kinematics = TrackedObjectKinematics(
            pose_with_covariance=pose,
            twist_with_covariance=twist,
            orientation_availability=OrientationAvailability.AVAILABLE,
        )
        label = labels.label_of(names[int(tracks.class_index[i])])
        objects.append(
            TrackedObject(
                object_id=UUID(object_uuid(vehicle, sensor, int(tracks.id[i]))),
                existence_probability=float(existence[i]),
                classification=(ObjectClassification(label, 1.0),),
                kinematics=kinematics,
                shape=Shape(ShapeType.BOUNDING_BOX, dimensions=Vector3(length, width, height)),
            )
        )
    return TrackedObjects(Header(time_of(stamp_ns), frame_id), tuple(objects))
