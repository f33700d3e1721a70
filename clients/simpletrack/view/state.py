"""What the view shows: the latest frame of each sensor (and of each fused vehicle) and its
running figures, as JSON.

Zenoh's callbacks only store references under a lock (latest wins, a few deque appends);
decoding detections and building JSON happen on the HTTP threads, at the rate pages ask for.
"""

from __future__ import annotations

import math
import threading
import time
from collections import deque
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

from simpletrack.client.subscriber import TrackMessage, VehicleTrackMessage
from simpletrack.view.vehicle import (
    MOUNT_ASSUMED,
    MOUNT_DETECTIONS,
    MOUNT_TRACKS,
    boxes_json,
    contributors_json,
    fused_transform,
    placement,
    sensor_colour,
    skipped_because,
    vehicle_pose,
)
from simpletrack.wire import Rejection, decode_detection_frame
from simpletrack.wire.codec import DecodedDetections
from simpletrack.wire.keys import VEHICLE_STREAM
from simpletrack.wire.reasons import STATE_NAMES

RATE_WINDOW_S = 3.0  # frames/s over the arrivals of the last few seconds
RECENT_FRAMES = 50  # latency and tracks-per-frame figures over this many frames
MAX_SENSORS = 10_000  # a flood of sensor names must not grow memory without end


@dataclass(frozen=True, slots=True)
class Fov:
    """A sensor's field of view: opening angle (degrees, centred on its x axis) and range (m)."""

    deg: float
    range_m: float


@dataclass
class _Stream:
    last: TrackMessage | VehicleTrackMessage
    frames: int = 0
    arrivals: deque[float] = field(default_factory=lambda: deque(maxlen=256))
    latency: deque[float] = field(default_factory=lambda: deque(maxlen=RECENT_FRAMES))
    counts: deque[int] = field(default_factory=lambda: deque(maxlen=RECENT_FRAMES))


@dataclass(frozen=True, slots=True)
class _RawDetections:
    payload: bytes
    received_ns: int


def _r(v: float, digits: int = 3) -> float:
    return round(float(v), digits)


def ego_of(pose: list[float] | None) -> dict[str, float] | None:
    """Position and heading of a sensor->world pose (row-major 4x4), None without one."""
    if pose is None:
        return None
    return {"x": _r(pose[3]), "y": _r(pose[7]), "yaw": _r(math.atan2(pose[4], pose[0]), 4)}


def tracks_json(msg: TrackMessage | VehicleTrackMessage) -> list[dict[str, Any]]:
    t = msg.tracks
    names = msg.class_names()
    return [
        {
            "id": int(t.id[i]),
            "class": names[i],
            "x": _r(t.center[i, 0]),
            "y": _r(t.center[i, 1]),
            "z": _r(t.center[i, 2]),
            "l": _r(t.size[i, 0]),
            "w": _r(t.size[i, 1]),
            "h": _r(t.size[i, 2]),
            "yaw": _r(t.yaw[i], 4),
            "vx": _r(t.velocity[i, 0]),
            "vy": _r(t.velocity[i, 1]),
            "score": _r(t.score[i]),
            "state": STATE_NAMES.get(int(t.state[i]), "unknown"),
            "hits": int(t.hits[i]),
            "age": int(t.age[i]),
        }
        for i in range(len(t))
    ]


def decode_detections(raw: _RawDetections) -> DecodedDetections | None:
    decoded = decode_detection_frame(raw.payload)
    return None if isinstance(decoded, Rejection) else decoded


def _detections_out(
    raw: _RawDetections, decoded: DecodedDetections, boxes: list[dict[str, Any]]
) -> dict[str, Any]:
    return {
        "seq": decoded.frame.seq,
        "stamp_ns": decoded.frame.stamp_ns,
        "received_ns": raw.received_ns,
        "boxes": boxes,
    }


def detections_json(raw: _RawDetections) -> dict[str, Any] | None:
    """The boxes of a detection frame, moved to the world frame when it carries a pose (where
    the service puts its tracks then); None for a payload that does not decode."""
    decoded = decode_detections(raw)
    if decoded is None:
        return None
    return _detections_out(raw, decoded, boxes_json(decoded, decoded.pose))


class ViewState:
    """Latest track frame (and detection frame) per ``vehicle/sensor``, and the latest fused
    frame per ``vehicle/@vehicle``, with rates and latency.

    ``version`` grows with every frame stored; ``wait_newer`` lets a page's event stream sleep
    until there is something new (or the state is closed)."""

    def __init__(self, fov: Mapping[str, Fov] | None = None, detections: bool = False) -> None:
        self.fov = dict(fov or {})
        self.detections_enabled = detections
        self._cond = threading.Condition()
        self._streams: dict[str, _Stream] = {}
        self._detections: dict[str, _RawDetections] = {}
        # Per fused vehicle, per sensor: the stamp of the latest message its frames produced
        # and the pose that message echoes (the sensor's sensor -> world pose, or None).
        self._applied: dict[str, dict[str, tuple[int, list[float] | None]]] = {}
        self.version = 0
        self.closed = False

    # ---------------------------------------------------------------- Zenoh's side
    def _store(self, name: str, msg: TrackMessage | VehicleTrackMessage) -> bool:
        """Under the lock: ``msg`` as ``name``'s latest frame; False when there is no room."""
        now = time.monotonic()
        stream = self._streams.get(name)
        if stream is None:
            if len(self._streams) >= MAX_SENSORS:
                return False
            stream = self._streams[name] = _Stream(msg)
        stream.last = msg
        stream.frames += 1
        stream.arrivals.append(now)
        stream.latency.append(msg.latency_s)
        stream.counts.append(len(msg.tracks))
        self.version += 1
        self._cond.notify_all()
        return True

    def add_tracks(self, msg: TrackMessage) -> None:
        with self._cond:
            self._store(f"{msg.vehicle}/{msg.sensor}", msg)

    def add_vehicle_tracks(self, msg: VehicleTrackMessage) -> None:
        name = f"{msg.vehicle}/{VEHICLE_STREAM}"
        with self._cond:
            if self._store(name, msg):
                applied = self._applied.setdefault(name, {})
                applied[msg.frame.sensor] = (msg.stamp_ns, msg.frame.pose)

    def add_detections(self, name: str, payload: bytes, received_ns: int) -> None:
        with self._cond:
            if name not in self._detections and len(self._detections) >= MAX_SENSORS:
                return
            self._detections[name] = _RawDetections(payload, received_ns)
            self.version += 1
            self._cond.notify_all()

    # ---------------------------------------------------------------- the pages' side
    def names(self) -> list[str]:
        with self._cond:
            return sorted(self._streams.keys() | self._detections.keys())

    def wait_newer(self, version: int, timeout: float) -> int:
        """The version once it is past ``version``, or after ``timeout`` s, or once closed."""
        with self._cond:
            self._cond.wait_for(lambda: self.version > version or self.closed, timeout)
            return self.version

    def close(self) -> None:
        with self._cond:
            self.closed = True
            self._cond.notify_all()

    def _fov_json(self, vehicle: str, sensor: str) -> dict[str, float] | None:
        fov = self.fov.get(f"{vehicle}/{sensor}") or self.fov.get(sensor)
        return None if fov is None else {"deg": fov.deg, "range": fov.range_m}

    def sensor_json(self, name: str) -> dict[str, Any] | None:
        """One stream's latest frame and figures (a vehicle's fused one for
        ``vehicle/@vehicle``: ``vehicle_json``); None for a stream not seen."""
        vehicle, _, sensor = name.partition("/")
        if sensor == VEHICLE_STREAM:
            return self.vehicle_json(name)
        now = time.monotonic()
        with self._cond:
            stream = self._streams.get(name)
            raw = self._detections.get(name) if self.detections_enabled else None
            if stream is None and raw is None:
                return None
            figures = None if stream is None else _figures(stream, now)
            msg = None if stream is None else stream.last
        out: dict[str, Any] = {
            "kind": "sensor",
            "name": name,
            "vehicle": vehicle,
            "sensor": sensor,
            "fov": self._fov_json(vehicle, sensor),
            "detections": None if raw is None else detections_json(raw),
        }
        if msg is None:
            out.update(seq=None, stamp_ns=None, frame_id=None, ego=None, tracks=[], stats=None)
            return out
        out.update(
            seq=msg.seq,
            stamp_ns=msg.stamp_ns,
            received_ns=msg.received_ns,
            frame_id=msg.frame.frame_id,
            instance=msg.frame.instance,
            pose=msg.frame.pose,
            ego=ego_of(msg.frame.pose),
            tracks=tracks_json(msg),
            stats=figures,
        )
        return out

    def vehicle_json(self, name: str) -> dict[str, Any] | None:
        """A vehicle's latest fused frame (``name`` is ``vehicle/@vehicle``): its tracks with
        existence and contributors, and per fused sensor its condition, colour, field of
        view, placement and latest detections (in the tracking frame, as the service puts
        them); None for a vehicle not seen."""
        now = time.monotonic()
        with self._cond:
            stream = self._streams.get(name)
            if stream is None or not isinstance(stream.last, VehicleTrackMessage):
                return None
            msg = stream.last
            figures = _figures(stream, now)
            applied = dict(self._applied.get(name, {}))
            raws = {
                s: self._detections.get(f"{msg.vehicle}/{s}") if self.detections_enabled else None
                for s in msg.sensors
            }
        world = msg.frame.pose is not None
        conditions = list(msg.frame.sensor_state)
        sensors = [
            self._fused_sensor(msg.vehicle, i, s, conditions[i], raws[s], applied.get(s), world)
            for i, s in enumerate(msg.sensors)
        ]
        tracks = tracks_json(msg)
        stamps = msg.tracks.sensor_stamp_ns
        existence = msg.existence
        latest = {s: stamp for s, (stamp, _) in applied.items()}
        for i, t in enumerate(tracks):
            t["existence"] = _r(existence[i])
            t["contributors"] = (
                []
                if stamps is None
                else contributors_json(
                    msg.sensors, conditions, stamps[i].tolist(), msg.stamp_ns, latest
                )
            )
        ego, ego_from = _vehicle_ego(world, sensors)
        return {
            "kind": "vehicle",
            "name": name,
            "vehicle": msg.vehicle,
            "sensor": VEHICLE_STREAM,
            "fov": None,
            "detections": None,
            "seq": msg.seq,
            "stamp_ns": msg.stamp_ns,
            "received_ns": msg.received_ns,
            "frame_id": msg.frame.frame_id,
            "instance": msg.frame.instance,
            "pose": msg.frame.pose,
            "source": {"sensor": msg.frame.sensor, "seq": msg.frame.sensor_seq},
            "ego": ego,
            "ego_from": ego_from,
            "sensors": [{k: v for k, v in s.items() if not k.startswith("_")} for s in sensors],
            "tracks": tracks,
            "stats": figures,
        }

    def _fused_sensor(
        self,
        vehicle: str,
        index: int,
        sensor: str,
        condition: str,
        raw: _RawDetections | None,
        applied: tuple[int, list[float] | None] | None,
        world: bool,
    ) -> dict[str, Any]:
        """One fused sensor of a vehicle's view (keys starting with ``_`` stay here)."""
        decoded = None if raw is None else decode_detections(raw)
        transform = None if decoded is None else fused_transform(decoded, world)
        detections = None
        skipped = None
        # Its placement: the newest of its detection frame's transform and (tracked in the
        # world frame) the pose its latest message echoes; else the vehicle's origin.
        mount, mount_from, mount_stamp = None, MOUNT_ASSUMED, -1
        if raw is not None and decoded is not None:
            if transform is None:
                skipped = skipped_because(decoded, world)
            else:
                boxes = boxes_json(decoded, transform)
                detections = _detections_out(raw, decoded, boxes)
                mount = placement(transform)
                mount_from, mount_stamp = MOUNT_DETECTIONS, decoded.frame.stamp_ns
        if world and applied is not None and applied[1] is not None and applied[0] > mount_stamp:
            mount, mount_from = placement(applied[1]), MOUNT_TRACKS
        if mount is None and not world:
            mount = {"x": 0.0, "y": 0.0, "yaw": 0.0}
        return {
            "name": sensor,
            "state": str(condition),
            "colour": sensor_colour(index),
            "fov": self._fov_json(vehicle, sensor),
            "mount": mount,
            "mount_from": mount_from if mount is not None else None,
            "applied_stamp_ns": None if applied is None else applied[0],
            "detections": detections,
            "detections_skipped": skipped,
            "_vehicle_pose": None if decoded is None or not world else vehicle_pose(decoded),
        }

    def state_json(self) -> dict[str, Any]:
        """Every stream's latest frame: what ``/state.json`` serves; the sensors' under
        ``sensors``, the fused vehicles' (``vehicle/@vehicle``) under ``vehicles``."""
        frames = {n: self.sensor_json(n) for n in self.names()}
        fused = f"/{VEHICLE_STREAM}"
        return {
            "detections_enabled": self.detections_enabled,
            "sensors": {n: f for n, f in frames.items() if f is not None and not n.endswith(fused)},
            "vehicles": {n: f for n, f in frames.items() if f is not None and n.endswith(fused)},
        }

    def event_json(self, chosen: str | None) -> dict[str, Any]:
        """One push to a page: the streams seen so far and the chosen one's latest frame
        (none chosen, or one not seen: the first fused vehicle, else the first sensor)."""
        names = self.names()
        if chosen not in names:
            chosen = default_stream(names)
        return {
            "detections_enabled": self.detections_enabled,
            "names": names,
            "frame": None if chosen is None else self.sensor_json(chosen),
        }


def default_stream(names: list[str]) -> str | None:
    """What a page shows when it names nothing: a fused vehicle when there is one (what
    planners of a fusing service receive), else the first sensor."""
    fused = [n for n in names if n.endswith(f"/{VEHICLE_STREAM}")]
    return fused[0] if fused else (names[0] if names else None)


def _vehicle_ego(
    world: bool, sensors: list[dict[str, Any]]
) -> tuple[dict[str, float] | None, str | None]:
    """Where the vehicle is in its tracking frame, and what says so: the origin of its own
    frame; in the world frame, a sensor's pose times its inverse extrinsic, else the first
    sensor's placement (its pose)."""
    if not world:
        return {"x": 0.0, "y": 0.0, "yaw": 0.0}, "vehicle frame"
    for s in sensors:
        if s["_vehicle_pose"] is not None:
            return placement(s["_vehicle_pose"]), f"{s['name']} pose and extrinsic"
    for s in sensors:
        if s["mount"] is not None:
            return dict(s["mount"]), f"{s['name']} pose"
    return None, None


def _figures(s: _Stream, now: float) -> dict[str, Any]:
    recent = [t for t in s.arrivals if now - t <= RATE_WINDOW_S]
    span = recent[-1] - recent[0] if len(recent) > 1 else 0.0
    latency = sorted(s.latency)
    return {
        "frames": s.frames,
        "rate_hz": _r((len(recent) - 1) / span, 2) if span > 0 else 0.0,
        "latency_s": _r(s.latency[-1], 4),
        "latency_p50_s": _r(latency[len(latency) // 2], 4),
        "tracks": len(s.last.tracks),
        "tracks_per_frame": _r(sum(s.counts) / len(s.counts), 2),
        "age_s": _r((time.time_ns() - s.last.received_ns) * 1e-9, 2),
        "by_state": {
            name: int((s.last.tracks.state == code).sum()) for code, name in STATE_NAMES.items()
        },
    }
