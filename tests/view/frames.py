"""Track and detection frames with known contents, put on Zenoh the way the service would."""

from __future__ import annotations

import dataclasses
import math
import time
from dataclasses import dataclass

import numpy as np
import zenoh

from simpletrack.client.subscriber import VehicleTrackMessage
from simpletrack.wire import (
    BoxArrays,
    Rejection,
    TrackArrays,
    decode_vehicle_track_frame,
    encode_detection_frame,
    encode_track_frame,
    encode_vehicle_track_frame,
)
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


def pose_at(x: float, y: float, yaw: float, z: float = 0.0) -> list[float]:
    c, s = math.cos(yaw), math.sin(yaw)
    return [c, -s, 0.0, x, s, c, 0.0, y, 0.0, 0.0, 1.0, z, 0.0, 0.0, 0.0, 1.0]


def in_sensor_frame(t: Known, transform: list[float]) -> Known:
    """``t`` (in the tracking frame) as seen by a sensor at ``transform`` (sensor ->
    tracking frame, level): what its detection frame carries."""
    m = np.array(transform, np.float64).reshape(4, 4)
    inv = np.linalg.inv(m)
    x, y, _ = inv[:3, :3] @ np.array([t.x, t.y, 0.8]) + inv[:3, 3]
    yaw = t.yaw - math.atan2(m[1, 0], m[0, 0])
    return Known(t.id, float(x), float(y), t.l, t.w, yaw, t.state, cls=t.cls)


def vehicle_arrays(
    tracks: list[Known], existence: list[float], stamps: list[list[int]]
) -> TrackArrays:
    """A fused frame's columns: ``stamps`` (N, S) each sensor's last update, -1 for never."""
    t = track_arrays(tracks)
    n = len(tracks)
    return dataclasses.replace(
        t,
        age_s=np.full(n, 2.0),
        time_since_update_s=np.zeros(n),
        existence=np.array(existence, np.float64),
        sensor_stamp_ns=np.array(stamps, np.int64).reshape(n, -1),
    )


def vehicle_frame(
    vehicle: str,
    seq: int,
    stamp_ns: int,
    source: str,
    sensors: list[str],
    states: list[str],
    columns: TrackArrays,
    pose: list[float] | None = None,
) -> bytes:
    now = time.time_ns()
    return encode_vehicle_track_frame(
        vehicle=vehicle,
        seq=seq,
        stamp_ns=stamp_ns,
        sensor=source,
        sensor_seq=seq,
        frame_id="world" if pose else "base_link",
        pose=pose,
        instance="svc-test",
        received_ns=now,
        published_ns=now,
        sensors=sensors,
        sensor_state=states,
        tracks=columns,
        epoch=1,
    )


def vehicle_message(payload: bytes, received_ns: int | None = None) -> VehicleTrackMessage:
    """A fused frame as ``VehicleTrackSubscriber`` hands it over."""
    decoded = decode_vehicle_track_frame(payload)
    assert not isinstance(decoded, Rejection), decoded
    frame, tracks = decoded
    key = f"fleet/{frame.vehicle}/@vehicle/tracks"
    return VehicleTrackMessage(key, frame, tracks, received_ns or time.time_ns())


def detection_frame(
    vehicle: str,
    sensor: str,
    seq: int,
    tracks: list[Known],
    pose: list[float] | None = None,
    extrinsic: list[float] | None = None,
    stamp_ns: int | None = None,
) -> bytes:
    """Detection boxes where ``tracks`` are (in the sensor frame)."""
    t = track_arrays(tracks)
    boxes = BoxArrays(
        classes=CLASSES,
        class_index=t.class_index,
        center=t.center,
        size=t.size,
        yaw=t.yaw,
        score=t.score,
    )
    return encode_detection_frame(
        vehicle=vehicle,
        sensor=sensor,
        seq=seq,
        stamp_ns=time.time_ns() if stamp_ns is None else stamp_ns,
        frame_id=sensor,
        boxes=boxes,
        pose=None if pose is None else np.array(pose).reshape(4, 4),
        extrinsic=None if extrinsic is None else np.array(extrinsic).reshape(4, 4),
    )


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


class VehicleSender:
    """Puts a fused vehicle's track frames (as the service would) and its sensors' detection
    frames (as the vehicle would)."""

    def __init__(
        self, session: zenoh.Session, vehicle: str, sensors: list[str], prefix: str = "fleet"
    ):
        keys = Keys(prefix)
        self.vehicle, self.sensors, self.seq = vehicle, sensors, 0
        self._tracks = session.declare_publisher(keys.vehicle_tracks(vehicle))
        self._dets = {s: session.declare_publisher(keys.detections(vehicle, s)) for s in sensors}

    def wait_matched(self) -> None:
        wait_for(lambda: self._tracks.matching_status.matching, 10, "the view's subscriber")
        for pub in self._dets.values():
            wait_for(lambda p=pub: p.matching_status.matching, 10, "a detections subscriber")

    def tracks(
        self,
        source: str,
        columns: TrackArrays,
        states: list[str],
        stamp_ns: int,
        pose: list[float] | None = None,
    ) -> None:
        self.seq += 1
        payload = vehicle_frame(
            self.vehicle, self.seq, stamp_ns, source, self.sensors, states, columns, pose
        )
        self._tracks.put(payload)

    def detections(self, sensor: str, payload: bytes) -> None:
        self._dets[sensor].put(payload)

    def undeclare(self) -> None:
        self._tracks.undeclare()  # type: ignore[no-untyped-call]
        for pub in self._dets.values():
            pub.undeclare()  # type: ignore[no-untyped-call]
