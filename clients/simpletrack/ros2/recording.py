"""What ``record --ros2`` and ``demo --ros2`` write in a ROS 2 bag: the service's frames as
Autoware messages, by the bridge's conversion (``tracks_to_tracked_objects`` and its uuid rule)
and its inverse for detections. The bag itself is simpletrack.mcap.ros2's."""

from __future__ import annotations

from simpletrack.ros2.codec import encode_detected_objects, encode_tracked_objects
from simpletrack.ros2.convert import quaternion_of, rotate, time_of, tracks_to_tracked_objects
from simpletrack.ros2.labels import PRESET_LABELS, LabelMap, label_map
from simpletrack.ros2.messages import (
    DETECTED_OBJECTS,
    TRACKED_OBJECTS,
    DetectedObject,
    DetectedObjectKinematics,
    DetectedObjects,
    Header,
    ObjectClassification,
    OrientationAvailability,
    Point,
    Pose,
    PoseWithCovariance,
    Shape,
    ShapeType,
    Twist,
    TwistWithCovariance,
    Vector3,
)
from simpletrack.ros2.typehash import MSG_DIR, type_hash
from simpletrack.wire import (
    BoxArrays,
    Rejection,
    decode_detection_frame,
    decode_track_frame,
    decode_vehicle_track_frame,
)
from simpletrack.wire.keys import DETECTIONS, TRACKS, VEHICLE_STREAM


def preset_labels(classes: tuple[str, ...]) -> LabelMap:
    """The label map of the preset whose classes a message's class table names most (ties: the
    first of nuscenes, kitti, wod): a service's own table gives its preset's map, the one
    ``simpletrack bridge ros2`` uses for it."""
    best = max(
        PRESET_LABELS,
        key=lambda p: sum(c in PRESET_LABELS[p].values() for c in classes),
    )
    return label_map(best)


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


class AutowareMessages:
    """What ``record --ros2`` writes for a raw message (``simpletrack.mcap.ros2.Ros2Messages``):
    a detection frame as DetectedObjects, a sensor's or a fused vehicle's tracks as
    TrackedObjects (``tracks_to_tracked_objects``: the bridge's conversion and uuid rule, the
    global id from the key's vehicle and sensor), each message checked by the wire's decoder
    first. ``labels``: a preset or ``LABEL=class`` pairs (the bridge's ``--labels``); None:
    each message's preset (``preset_labels``)."""

    msg_dir = MSG_DIR

    def __init__(self, labels: str | None = None) -> None:
        self._fixed = label_map(labels) if labels is not None else None
        self.labels = (
            f"{self._fixed.name}: {self._fixed.describe()}"
            if self._fixed is not None
            else "each message's preset (nuscenes, kitti or wod) by its class table"
        )
        self._by_classes: dict[tuple[str, ...], LabelMap] = {}

    def labels_for(self, classes: tuple[str, ...]) -> LabelMap:
        if self._fixed is not None:
            return self._fixed
        labels = self._by_classes.get(classes)
        if labels is None:
            labels = self._by_classes[classes] = preset_labels(classes)
        return labels

    def type_hash(self, type_name: str) -> str:
        return type_hash(type_name)

    def convert(
        self, leaf: str, vehicle: str, sensor: str, payload: bytes
    ) -> tuple[str, bytes] | None:
        if leaf == DETECTIONS:
            decoded = decode_detection_frame(payload)
            if isinstance(decoded, Rejection):
                return None
            boxes = decoded.boxes
            detected = boxes_to_detected_objects(
                boxes,
                stamp_ns=decoded.frame.stamp_ns,
                frame_id=decoded.frame.frame_id,
                labels=self.labels_for(boxes.classes),
            )
            return DETECTED_OBJECTS, encode_detected_objects(detected)
        if leaf != TRACKS:
            return None
        tracks = (
            decode_vehicle_track_frame(payload)
            if sensor == VEHICLE_STREAM
            else decode_track_frame(payload)
        )
        if isinstance(tracks, Rejection):
            return None
        frame, arrays = tracks
        tracked = tracks_to_tracked_objects(
            arrays,
            vehicle=vehicle,
            sensor=sensor,
            stamp_ns=frame.stamp_ns,
            frame_id=frame.frame_id,
            labels=self.labels_for(arrays.classes),
        )
        return TRACKED_OBJECTS, encode_tracked_objects(tracked)
