"""What ``record --ros2`` and ``demo --ros2`` write in a ROS 2 bag: the service's frames as
Autoware messages, by the bridge's conversion (simpletrack.ros2.convert:
``tracks_to_tracked_objects`` and its uuid rule, ``boxes_to_detected_objects`` for detections). The bag itself is simpletrack.mcap.ros2's."""

from __future__ import annotations

from simpletrack.ros2.codec import encode_detected_objects, encode_tracked_objects
from simpletrack.ros2.convert import boxes_to_detected_objects, tracks_to_tracked_objects
from simpletrack.ros2.labels import PRESET_LABELS, LabelMap, label_map
from simpletrack.ros2.messages import (
    DETECTED_OBJECTS,
    TRACKED_OBJECTS,
)
from simpletrack.ros2.typehash import MSG_DIR, type_hash
from simpletrack.wire import (
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
