"""Track and detection frames with known contents, put on Zenoh the way the service would."""

from __future__ import annotations

import math
import time
from dataclasses import dataclass

import numpy as np
import zenoh

from simpletrack.wire import BoxArrays, TrackArrays, encode_detection_frame, encode_track_frame
from simpletrack.wire.keys import Keys
from tests.service_helpers import wait_for

CLASSES = ("car", "pedestrian")


@dataclass(frozen=True)
class Known:
    """One track: where it is, how big, which way it points and moves, its state code."""

    id: int
    x: float
    y: float
    l: float  # noqa: E741  (length, as on the wire)
    w: float
    yaw: float
    state: int  # WireTrackState
    vx: float = 0.0
    vy: float = 0.0
    cls: int = 0


def track_arrays(tracks: list[Known]) -> TrackArrays:
    n = len(tracks)
    return TrackArrays(
        classes=CLASSES,
        id=np.array([t.id for t in tracks], np.int64),
        class_index=np.array([t.cls for t in tracks], np.int32),
        center=np.array([[t.x, t.y, 0.8] for t in tracks], np.float32).reshape(n, 3),
        size=np.array([[t.l, t.w, 1.6] for t in tracks], np.float32).reshape(n, 3),
        yaw=np.array([t.yaw for t in tracks], np.float32),
        score=np.full(n, 0.9),
        velocity=np.array([[t.vx, t.vy, 0.0] for t in tracks], np.float32).reshape(n, 3),
        state=np.array([t.state for t in tracks], np.int32),
        hits=np.full(n, 5, np.int32),
        age=np.full(n, 7, np.int32),
        time_since_update=np.array([1 if t.state == 2 else 0 for t in tracks], np.int32),
    )


def pose_at(x: float, y: float, yaw: float) -> list[float]:
    c, s = math.cos(yaw), math.sin(yaw)
    return [c, -s, 0.0, x, s, c, 0.0, y, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 1.0]


class Sender:
    """Puts track (and detection) frames of one sensor, as the service and a vehicle would."""

    def __init__(self, session: zenoh.Session, vehicle: str, sensor: str, prefix: str = "fleet"):
        keys = Keys(prefix)
        self.vehicle, self.sensor, self.seq = vehicle, sensor, 0
        self._tracks = session.declare_publisher(keys.tracks(vehicle, sensor))
        self._dets = session.declare_publisher(keys.detections(vehicle, sensor))

    def wait_matched(self, detections: bool = False) -> None:
        wait_for(lambda: self._tracks.matching_status.matching, 10, "the view's subscriber")
        if detections:
            wait_for(lambda: self._dets.matching_status.matching, 10, "a detections subscriber")

    def tracks(
        self, tracks: list[Known], pose: list[float] | None = None, stamp_ns: int | None = None
    ) -> None:
        self.seq += 1
        now = time.time_ns()
        self._tracks.put(
            encode_track_frame(
                vehicle=self.vehicle,
                sensor=self.sensor,
                seq=self.seq,
                stamp_ns=now if stamp_ns is None else stamp_ns,
                frame_id="world" if pose else "lidar",
                pose=pose,
                key_frame=True,
                instance="svc-test",
                received_ns=now,
                published_ns=now,
                tracks=track_arrays(tracks),
            )
        )

    def detections(self, tracks: list[Known], pose: list[float] | None = None) -> None:
        """Detection boxes where ``tracks`` are (in the sensor frame when ``pose`` is given)."""
        t = track_arrays(tracks)
        boxes = BoxArrays(
            classes=CLASSES,
            class_index=t.class_index,
            center=t.center,
            size=t.size,
            yaw=t.yaw,
            score=t.score,
        )
        self._dets.put(
            encode_detection_frame(
                vehicle=self.vehicle,
                sensor=self.sensor,
                seq=self.seq,
                stamp_ns=time.time_ns(),
                frame_id="lidar",
                boxes=boxes,
                pose=None if pose is None else np.array(pose).reshape(4, 4),
            )
        )

    def undeclare(self) -> None:
        self._tracks.undeclare()  # type: ignore[no-untyped-call]
        self._dets.undeclare()  # type: ignore[no-untyped-call]
