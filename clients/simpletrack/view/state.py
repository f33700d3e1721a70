"""What the view shows: the latest frame of each sensor and its running figures, as JSON.

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

import numpy as np

from simpletrack.client.subscriber import TrackMessage
from simpletrack.wire import Rejection, WireTrackState, decode_detection_frame

RATE_WINDOW_S = 3.0  # frames/s over the arrivals of the last few seconds
RECENT_FRAMES = 50  # latency and tracks-per-frame figures over this many frames
MAX_SENSORS = 10_000  # a flood of sensor names must not grow memory without end
STATE_NAMES = {int(s): s.name.lower() for s in WireTrackState}


@dataclass(frozen=True, slots=True)
class Fov:
    """A sensor's field of view: opening angle (degrees, centred on its x axis) and range (m)."""

    deg: float
    range_m: float


@dataclass
class _Stream:
    last: TrackMessage
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


def tracks_json(msg: TrackMessage) -> list[dict[str, Any]]:
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


def detections_json(raw: _RawDetections) -> dict[str, Any] | None:
    """The boxes of a detection frame, moved to the world frame when it carries a pose (where
    the service puts its tracks then); None for a payload that does not decode."""
    decoded = decode_detection_frame(raw.payload)
    if isinstance(decoded, Rejection):
        return None
    b = decoded.boxes
    xy = b.center[:, :2].astype(np.float64)
    yaw = b.yaw.astype(np.float64)
    if decoded.pose is not None:
        rot, shift = decoded.pose[:2, :2], decoded.pose[:2, 3]
        xy = xy @ rot.T + shift
        yaw = yaw + math.atan2(decoded.pose[1, 0], decoded.pose[0, 0])
    names = b.class_names()
    return {
        "seq": decoded.frame.seq,
        "stamp_ns": decoded.frame.stamp_ns,
        "received_ns": raw.received_ns,
        "boxes": [
            {
                "class": names[i],
                "x": _r(xy[i, 0]),
                "y": _r(xy[i, 1]),
                "l": _r(b.size[i, 0]),
                "w": _r(b.size[i, 1]),
                "yaw": _r(yaw[i], 4),
                "score": _r(b.score[i]),
            }
            for i in range(len(b))
        ],
    }


class ViewState:
    """Latest track frame (and detection frame) per ``vehicle/sensor``, with rates and latency.

    ``version`` grows with every frame stored; ``wait_newer`` lets a page's event stream sleep
    until there is something new (or the state is closed)."""

    def __init__(self, fov: Mapping[str, Fov] | None = None, detections: bool = False) -> None:
        self.fov = dict(fov or {})
        self.detections_enabled = detections
        self._cond = threading.Condition()
        self._streams: dict[str, _Stream] = {}
        self._detections: dict[str, _RawDetections] = {}
        self.version = 0
        self.closed = False

    # ---------------------------------------------------------------- Zenoh's side
    def add_tracks(self, msg: TrackMessage) -> None:
        name = f"{msg.vehicle}/{msg.sensor}"
        now = time.monotonic()
        with self._cond:
            stream = self._streams.get(name)
            if stream is None:
                if len(self._streams) >= MAX_SENSORS:
                    return
                stream = self._streams[name] = _Stream(msg)
            stream.last = msg
            stream.frames += 1
            stream.arrivals.append(now)
            stream.latency.append(msg.latency_s)
            stream.counts.append(len(msg.tracks))
            self.version += 1
            self._cond.notify_all()

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

    def sensor_json(self, name: str) -> dict[str, Any] | None:
        """One sensor's latest frame and figures; None for a sensor not seen."""
        now = time.monotonic()
        with self._cond:
            stream = self._streams.get(name)
            raw = self._detections.get(name) if self.detections_enabled else None
            if stream is None and raw is None:
                return None
            figures = None if stream is None else _figures(stream, now)
            msg = None if stream is None else stream.last
        vehicle, _, sensor = name.partition("/")
        fov = self.fov.get(name) or self.fov.get(sensor)
        out: dict[str, Any] = {
            "name": name,
            "vehicle": vehicle,
            "sensor": sensor,
            "fov": None if fov is None else {"deg": fov.deg, "range": fov.range_m},
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

    def state_json(self) -> dict[str, Any]:
        """Every sensor's latest frame: what ``/state.json`` serves."""
        sensors = {n: self.sensor_json(n) for n in self.names()}
        return {
            "detections_enabled": self.detections_enabled,
            "sensors": {n: s for n, s in sensors.items() if s is not None},
        }

    def event_json(self, chosen: str | None) -> dict[str, Any]:
        """One push to a page: the sensors seen so far and the chosen one's latest frame."""
        names = self.names()
        if chosen not in names:
            chosen = names[0] if names else None
        return {
            "detections_enabled": self.detections_enabled,
            "names": names,
            "frame": None if chosen is None else self.sensor_json(chosen),
        }


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
