"""``DetectionPublisher``: the vehicle side of the service. One per vehicle sensor.

    from simpletrack.client import DetectionPublisher, ZenohOptions

    with DetectionPublisher.connect("veh01", "lidar", classes=("vehicle", "pedestrian"),
                                    options=ZenohOptions(connect=["tcp/127.0.0.1:7447"])) as pub:
        pub.publish(boxes)                      # BoxArrays, [Box, ...] or simpletrack.core.Boxes
        for err in pub.errors(timeout=0):       # frames the service refused, if any
            print(err.seq, err.reason, err.detail)

Frames are stamped with a per-sensor ``seq`` (strictly increasing), the wall-clock
``stamp_ns`` unless one is given, and the publisher's ``session_id`` (random per publisher: the
service knows a restarted publisher by it and tracks it from its first frame). ``resume()`` asks
the service for the last seq it processed and continues after it.

Delivery: the publisher keeps its last ``cache_frames`` frames (100 by default: 10 s at
10 Hz, ~1 MB at 200 boxes a frame) and a service's subscriber asks it for the ones it missed
once it can reach the vehicle again (a router outage). A frame published while no service is
reachable is reported to ``on_undelivered`` (on the caller's thread, from ``publish()``) as
held (still in the cache) and, if the outage outlasts the cache, again as lost; the counts
are ``held`` and ``lost``, and ``delivering`` says whether a service is reachable now. A
service recovers held frames when it had heard from this publisher before the outage, or
tracks the sensor already (a vehicle rebooted while its router was away: the first frame it
hears asks the cache for those before); one that first hears of the sensor at its own start
takes only its latest frame (the service's ``history_frames``).

Errors the service sends back on ``<prefix>/<vehicle>/<sensor>/errors`` reach ``on_error`` (called on a Zenoh thread: keep it short) and the ``errors()`` iterator.

A sensor whose vehicle fuses its sensors gives its mounting, ``extrinsic`` (4x4
sensor->vehicle): every frame then carries it (DetectionFrame version 2); a vehicle without
poses must give it (docs/VEHICLES.md).
"""

from __future__ import annotations

import contextlib
import logging
import re
import secrets
import sys
import threading
import time
from collections import deque
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np
import numpy.typing as npt
import zenoh
from zenoh import ext

from simpletrack.client.exit_hooks import close_before_thread_join
from simpletrack.client.mailbox import Mailbox
from simpletrack.session import DEFAULT_LISTEN, Congestion, ZenohOptions, open_session
from simpletrack.wire import (
    BoxArrays,
    FrameError,
    Rejection,
    decode_message,
    encode_detection_frame,
)
from simpletrack.wire.codec import rigid_transform, transform_list
from simpletrack.wire.decoding import Reject
from simpletrack.wire.keys import Keys
from simpletrack.wire.messages import NAME_PATTERN, SensorStatus, ServiceStatus

if TYPE_CHECKING:
    from typing_extensions import TypeIs

    from simpletrack.wire.convert import Boxes

log = logging.getLogger(__name__)

MSGPACK = zenoh.Encoding("application/msgpack")
CONGESTION = {
    Congestion.BLOCK: zenoh.CongestionControl.BLOCK,
    Congestion.DROP: zenoh.CongestionControl.DROP,
}
DEFAULT_CACHE_FRAMES = 100  # 10 s of a 10 Hz sensor
# Lets a subscriber notice the last frames it missed even when the vehicle stops publishing;
# one tiny message per sensor per period.
DEFAULT_HEARTBEAT_S = 0.5
# wait_for_service's margin past the first match: a group's owner subscribes on seeing this
# publisher's token, a few milliseconds after another subscriber (its scout) may match.
SETTLE_S = 0.25


@dataclass(frozen=True, slots=True)
class Undelivered:
    """A frame published while no service was reachable. ``lost`` False: it is in the
    publisher's cache and goes out when a service asks for it after reconnecting; True: the
    outage outlasted the cache and the frame is gone."""

    seq: int
    lost: bool


@dataclass(frozen=True, slots=True)
class Box:
    """One detection, for callers that think in objects rather than arrays. ``x, y, z`` is
    the box centre, z up; ``yaw`` about +z from +x; ``l`` along the heading."""

    x: float
    y: float
    z: float
    yaw: float
    l: float  # noqa: E741 - the spec's name
    w: float
    h: float
    score: float
    cls: str
    vx: float | None = None
    vy: float | None = None


def check_name(kind: str, value: str) -> str:
    if not re.fullmatch(NAME_PATTERN, value):  # match's '$' lets a trailing newline through
        raise ValueError(
            f"{kind} id {value!r} must be 1-64 letters, digits, '_', '.' or '-' (no '/' or '*')"
        )
    return value


def check_extrinsic(extrinsic: npt.ArrayLike) -> list[float]:
    """A 4x4 sensor->vehicle transform (or its 16 values, row-major) as the wire's 16 floats;
    ValueError for anything the service would refuse (not 16 values, NaN, not rigid, a
    translation beyond 1e5 m)."""
    try:
        values = transform_list(extrinsic)
    except ValueError as e:
        raise ValueError(f"extrinsic must be a 4x4 transform: {e}") from None
    try:
        rigid_transform(values, "extrinsic")
    except Reject as r:
        raise ValueError(f"extrinsic: {r.detail}") from None
    return values


def _is_core_boxes(obj: object) -> TypeIs[Boxes]:
    # Only a process that has loaded the core can hold core Boxes: a vehicle that never
    # imports it never pays for it here.
    core = sys.modules.get("simpletrack.core.boxes")
    return core is not None and isinstance(obj, core.Boxes)


def box_list_to_arrays(boxes: Sequence[Box], classes: Sequence[str]) -> BoxArrays:
    """A list of ``Box``; class names outside ``classes`` are appended to the frame's table
    (the service then refuses them as ``unknown_class``, which is the honest outcome)."""
    table = list(classes)
    index = []
    for b in boxes:
        if b.cls not in table:
            table.append(b.cls)
        index.append(table.index(b.cls))
    n = len(boxes)
    with_velocity = n > 0 and all(b.vx is not None and b.vy is not None for b in boxes)
    return BoxArrays(
        classes=tuple(table),
        class_index=np.array(index, dtype=np.int32),
        center=np.array([(b.x, b.y, b.z) for b in boxes], dtype=np.float32).reshape(n, 3),
        size=np.array([(b.l, b.w, b.h) for b in boxes], dtype=np.float32).reshape(n, 3),
        yaw=np.array([b.yaw for b in boxes], dtype=np.float32),
        score=np.array([b.score for b in boxes], dtype=np.float64),
        velocity=np.array([(b.vx, b.vy) for b in boxes], dtype=np.float32).reshape(n, 2)
        if with_velocity
        else None,
    )


class DetectionPublisher:
    """Publishes one vehicle sensor's detection frames on ``<prefix>/<vehicle>/<sensor>/detections``."""

    def __init__(
        self,
        session: zenoh.Session,
        vehicle: str,
        sensor: str,
        *,
        classes: Sequence[str],
        prefix: str = "fleet",
        frame_id: str | None = None,
        congestion: Congestion = Congestion.BLOCK,
        on_error: Callable[[FrameError], None] | None = None,
        error_buffer: int = 1000,
        first_seq: int = 0,
        session_id: int | None = None,
        cache_frames: int = DEFAULT_CACHE_FRAMES,
        heartbeat_s: float = DEFAULT_HEARTBEAT_S,
        on_undelivered: Callable[[Undelivered], None] | None = None,
        extrinsic: npt.ArrayLike | None = None,
    ) -> None:
        self.vehicle = check_name("vehicle", vehicle)
        self.sensor = check_name("sensor", sensor)
        self.classes = tuple(classes)
        self.frame_id = frame_id or sensor
        # The sensor's mounting (sensor->vehicle), sent with every frame; None: not sent.
        self.extrinsic = None if extrinsic is None else check_extrinsic(extrinsic)
        self.keys = Keys(prefix)
        self.next_seq = first_seq
        # 63 random bits: two runs of one sensor's publisher never share an id in practice.
        self.session_id = secrets.randbits(63) if session_id is None else session_id
        self.sent = 0
        self.invalid_errors = 0
        self._session = session
        self._owns_session = False
        self._on_error = on_error
        self._errors: Mailbox[FrameError] = Mailbox(error_buffer)
        self._closed = False
        if cache_frames < 1:
            raise ValueError("cache_frames must be at least 1")
        if heartbeat_s <= 0:
            raise ValueError("heartbeat_s must be positive")
        self.cache_frames = cache_frames
        self.held = 0  # frames published while no service was reachable
        self.lost = 0  # of those, frames pushed out of the cache before a service came back
        self._on_undelivered = on_undelivered
        self._held: deque[int] = deque()  # seqs in the cache not yet seen by a service
        self._held_lock = threading.Lock()
        key = self.keys.detections(vehicle, sensor)
        self._publisher = ext.declare_advanced_publisher(
            session,
            key,
            encoding=MSGPACK,
            congestion_control=CONGESTION[Congestion(congestion)],
            cache=ext.CacheConfig(cache_frames),
            sample_miss_detection=ext.MissDetectionConfig(
                heartbeat=heartbeat_s, sporadic_heartbeat=None
            ),
            publisher_detection=True,
        )
        # The advanced publisher does not expose its matching status in Python: a plain
        # publisher on the same key, never used to put, tells whether a service is reachable.
        self._matching = session.declare_publisher(key)
        self._matching_listener = self._matching.declare_matching_listener(self._on_matching)
        self._error_sub = session.declare_subscriber(
            self.keys.errors(vehicle, sensor), self._on_error_sample
        )
        close_before_thread_join(self)

    @classmethod
    def connect(
        cls, vehicle: str, sensor: str, *, options: ZenohOptions | None = None, **kwargs: Any
    ) -> DetectionPublisher:
        """A publisher with a session of its own (closed by ``close()``). Without options it
        joins a service on this machine: peer mode, connecting to ``tcp/127.0.0.1:7447``."""
        session = open_session(options or default_options())
        try:
            pub = cls(session, vehicle, sensor, **kwargs)
        except BaseException:
            session.close()  # type: ignore[no-untyped-call]
            raise
        pub._owns_session = True
        return pub

    # ----------------------------------------------------------------- publishing
    def publish(
        self,
        boxes: BoxArrays | Sequence[Box] | Boxes,
        *,
        stamp_ns: int | None = None,
        pose: npt.ArrayLike | None = None,
        key_frame: bool = True,
        seq: int | None = None,
        extrinsic: npt.ArrayLike | None = None,
    ) -> int:
        """Send one frame; returns its ``seq``. ``pose`` is the optional 4x4 sensor->world;
        ``seq`` (default: one more than the last) may skip ahead, never go back;
        ``extrinsic`` (4x4 sensor->vehicle) replaces the publisher's for this frame. Core
        ``Boxes`` (codes index ``classes``) go through ``simpletrack.wire.convert``."""
        if isinstance(boxes, BoxArrays):
            arrays = boxes
        elif _is_core_boxes(boxes):
            from simpletrack.wire.convert import boxes_to_wire

            arrays = boxes_to_wire(boxes, self.classes)
        else:
            arrays = box_list_to_arrays(boxes, self.classes)
        return self.publish_arrays(
            arrays, stamp_ns=stamp_ns, pose=pose, key_frame=key_frame, seq=seq, extrinsic=extrinsic
        )

    def publish_arrays(
        self,
        boxes: BoxArrays,
        *,
        stamp_ns: int | None = None,
        pose: npt.ArrayLike | None = None,
        key_frame: bool = True,
        seq: int | None = None,
        extrinsic: npt.ArrayLike | None = None,
    ) -> int:
        if self._closed:
            raise RuntimeError("publisher is closed")
        mounting = self.extrinsic if extrinsic is None else check_extrinsic(extrinsic)
        if seq is None:
            seq = self.next_seq
        elif seq < self.next_seq:
            raise ValueError(f"seq {seq} is below the next one, {self.next_seq}: seq only grows")
        payload = encode_detection_frame(
            vehicle=self.vehicle,
            sensor=self.sensor,
            seq=seq,
            stamp_ns=time.time_ns() if stamp_ns is None else int(stamp_ns),
            frame_id=self.frame_id,
            boxes=boxes,
            pose=pose,
            key_frame=key_frame,
            session_id=self.session_id,
            extrinsic=mounting,
        )
        self._publisher.put(payload)
        self.next_seq = seq + 1
        self.sent += 1
        if not self.delivering:
            self._report_held(seq)
        return seq

    def last_processed(self, timeout: float = 2.0) -> SensorStatus | None:
        """What the service last tracked of this sensor (``last_seq``, ``last_stamp_ns``),
        from the status queryable of every instance that answers within ``timeout``; the
        latest stamp wins. None when no service holds the sensor."""
        selector = f"{self.keys.status('*')}?vehicle={self.vehicle};sensor={self.sensor}"
        best: SensorStatus | None = None
        for reply in self._session.get(selector, timeout=timeout):
            if reply.ok is None:
                continue
            status = decode_message(reply.ok.payload.to_bytes(), ServiceStatus)
            if isinstance(status, Rejection):
                continue
            for st in status.sensors:
                if (st.vehicle, st.sensor) != (self.vehicle, self.sensor):
                    continue
                if best is None or (st.last_stamp_ns or -1) > (best.last_stamp_ns or -1):
                    best = st
        return best

    def resume(self, timeout: float = 2.0) -> int | None:
        """Continue the stream after the last seq the service processed: the next frame
        gets that seq + 1 (never less than this publisher's own next one). Returns the
        service's last seq, or None (nothing known: numbering goes on unchanged)."""
        st = self.last_processed(timeout)
        if st is None or st.last_seq is None:
            return None
        self.next_seq = max(self.next_seq, st.last_seq + 1)
        return st.last_seq

    @property
    def delivering(self) -> bool:
        """True while some subscriber (a service) is reachable on this sensor's key."""
        # The stubs say bool; zenoh 1.10 returns a MatchingStatus.
        status: object = self._matching.matching_status
        return bool(getattr(status, "matching", status))

    def _report_held(self, seq: int) -> None:
        reports = [Undelivered(seq, lost=False)]
        with self._held_lock:
            self.held += 1
            self._held.append(seq)
            while len(self._held) > self.cache_frames:
                reports.append(Undelivered(self._held.popleft(), lost=True))
                self.lost += 1
        if self._on_undelivered is not None:
            for report in reports:
                try:
                    self._on_undelivered(report)
                except Exception:
                    log.exception("on_undelivered callback failed")

    def _on_matching(self, status: zenoh.MatchingStatus) -> None:
        if status.matching:
            # A service is back: what is still cached is its to ask for.
            with self._held_lock:
                self._held.clear()

    def wait_for_service(self, timeout: float) -> bool:
        """True once some subscriber matches this sensor's detections key, and SETTLE_S more
        have passed. Any subscriber counts: a recorder (``simpletrack record``), ``simpletrack
        view --detections`` or a group's scout (docs/SCALE.md) already listening makes this
        true before the sensor's owner subscribes; the owner subscribes on seeing this
        publisher's token, within milliseconds, and SETTLE_S covers that (its history query
        could otherwise race the first frames). Start recorders after the service answers
        (the demo does), or ask the service's status queryable."""
        deadline = time.monotonic() + timeout
        while True:
            if self.delivering:
                time.sleep(SETTLE_S)
                return True
            if time.monotonic() >= deadline:
                return False
            time.sleep(0.02)

    # ----------------------------------------------------------------- errors
    def _on_error_sample(self, sample: zenoh.Sample) -> None:
        msg = decode_message(sample.payload.to_bytes(), FrameError)
        if isinstance(msg, Rejection):
            self.invalid_errors += 1
            return
        self._errors.put(msg)
        if self._on_error is not None:
            try:
                self._on_error(msg)
            except Exception:  # a user callback must not kill Zenoh's thread
                log.exception("on_error callback failed")

    def errors(self, timeout: float | None = None) -> Iterator[FrameError]:
        """Errors received so far and, while ``timeout`` allows, more as they come: each
        wait for the next error lasts at most ``timeout`` s (None: until ``close()``)."""
        while True:
            err = self._errors.get(timeout)
            if err is None:
                return
            yield err

    @property
    def errors_received(self) -> int:
        return self._errors.put_count

    # ----------------------------------------------------------------- shutdown
    def close(self) -> None:
        """Stop; closes the session if this publisher opened it. Idempotent."""
        if self._closed:
            return
        self._closed = True
        self._errors.close()
        if self._owns_session:
            _close_quietly(self._session)
        else:
            entities = (self._error_sub, self._matching_listener, self._matching, self._publisher)
            for entity in entities:
                with contextlib.suppress(Exception):  # already gone with its session
                    entity.undeclare()  # type: ignore[no-untyped-call]

    def __enter__(self) -> DetectionPublisher:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def default_options() -> ZenohOptions:
    """Peer mode, no listening, connecting to a service on this machine (its default listen)."""
    return ZenohOptions(connect=list(DEFAULT_LISTEN))


def _close_quietly(session: zenoh.Session) -> None:
    try:
        if not session.is_closed():
            session.close()  # type: ignore[no-untyped-call]
    except Exception:
        pass
