"""``TrackSubscriber``: the planner side of the service. Receives decoded ``TrackFrame``s of one
sensor, one vehicle or the whole fleet, as a blocking iterator, a callback, or ``async for``.

    from simpletrack.client import TrackSubscriber

    with TrackSubscriber.connect(vehicle="veh01") as sub:      # every sensor of veh01
        for msg in sub:                                       # blocks; ends on close()
            print(msg.vehicle, msg.sensor, msg.seq, msg.tracks.id)

    async with TrackSubscriber.connect() as sub:              # the whole fleet
        async for msg in sub: ...

Messages are decoded on Zenoh's thread and wait in a bounded buffer (the newest ``buffer``
frames are kept; ``dropped`` counts the rest). ``close()`` wakes every waiting consumer and
closes the session the subscriber opened: no thread stays blocked at exit.

A frame already delivered (the same sensor, ``seq`` and ``stamp_ns``: what two instances of
a group would both send if one died between publishing a frame and the other hearing it) is
not delivered again; ``duplicates`` counts them. Nor is a frame of a fenced holder (an
instance paused or cut off after another took its stream over): its custody ``epoch`` is
below the highest the stream has shown; ``stale`` counts them (schemas/README.md, "Custody
epoch (fencing)"; ``simpletrack.client.stream_filter``).

A payload on a tracks key that does not decode is never silent: it is counted (``invalid``,
``invalid_reasons``), logged as a warning on this module's logger (at most one line a second,
with the count of those not logged), and handed to ``on_invalid`` if given.
"""

from __future__ import annotations

import contextlib
import logging
import threading
import time
from collections.abc import AsyncIterator, Callable, Iterator, Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, Generic, Self, TypeVar

import numpy as np
import numpy.typing as npt
import zenoh

from simpletrack.client.exit_hooks import close_before_thread_join
from simpletrack.client.mailbox import Mailbox
from simpletrack.client.publisher import _close_quietly, check_name, default_options
from simpletrack.client.stream_filter import StreamFilter, Verdict
from simpletrack.session import ZenohOptions, open_session
from simpletrack.wire import (
    Rejection,
    TrackArrays,
    TrackFrame,
    VehicleTrackFrame,
    decode_track_frame,
    decode_vehicle_track_frame,
)
from simpletrack.wire.keys import VEHICLE_STREAM, Keys
from simpletrack.wire.reasons import SensorCondition
from simpletrack.wire.track_ids import global_id, global_ids

if TYPE_CHECKING:
    from simpletrack.wire.convert import Boxes

log = logging.getLogger(__name__)
INVALID_LOG_INTERVAL_S = 1.0  # a stream of garbage must not flood the planner's log


class _TrackList:
    """What a sensor's and a vehicle's track messages share: the header's vehicle and stamp,
    the columns as names, boxes and ids, and fleet-unique ids ``<vehicle>/<sensor>/<id>``
    (the stream's ``sensor``: a sensor's name or ``@vehicle``)."""

    __slots__ = ()
    key: str
    frame: TrackFrame | VehicleTrackFrame
    tracks: TrackArrays
    received_ns: int

    @property
    def sensor(self) -> str:
        raise NotImplementedError

    @property
    def vehicle(self) -> str:
        return self.frame.vehicle

    @property
    def seq(self) -> int:
        return self.frame.seq

    @property
    def stamp_ns(self) -> int:
        return self.frame.stamp_ns

    @property
    def epoch(self) -> int | None:
        """The stream's custody epoch when the service sent one (TrackFrame version 3,
        VehicleTrackFrame version 2), else None."""
        return self.frame.epoch

    @property
    def latency_s(self) -> float:
        """Sensor stamp to arrival here; meaningful when the sensor stamps with wall-clock time."""
        return (self.received_ns - self.frame.stamp_ns) * 1e-9

    def class_names(self) -> list[str]:
        return [self.tracks.classes[i] for i in self.tracks.class_index.tolist()]

    def boxes(self, classes: Sequence[str] | None = None) -> Boxes:
        """The tracks as core ``Boxes`` (float64); class codes index ``classes`` (default:
        the service's table). Tracks of classes missing from ``classes`` are dropped.

        Needs the service extra (the core, through ``simpletrack.wire.convert``)."""
        from simpletrack.wire.convert import track_boxes_from_wire

        return track_boxes_from_wire(self.tracks, classes)

    def ids(self, classes: Sequence[str] | None = None) -> np.ndarray[Any, np.dtype[np.int64]]:
        """Track ids, in the order of ``boxes(classes)``."""
        ids: np.ndarray[Any, np.dtype[np.int64]] = self.tracks.id.astype(np.int64)
        if classes is None:
            return ids
        keep = np.array([n in classes for n in self.class_names()], dtype=bool)
        return np.asarray(ids[keep], dtype=np.int64)

    def global_id(self, i: int) -> str:
        """Track i's fleet-unique id ``<vehicle>/<sensor>/<id>`` (``<vehicle>/@vehicle/<id>``
        for a vehicle's fused tracks; schemas/README.md, "Track identity"): the same for as
        long as the track lives, never given to another track."""
        return global_id(self.frame.vehicle, self.sensor, int(self.tracks.id[i]))

    @property
    def global_ids(self) -> list[str]:
        """Every track's ``global_id``, in column order."""
        return global_ids(self.frame.vehicle, self.sensor, self.tracks.id)


@dataclass(frozen=True, slots=True)
class TrackMessage(_TrackList):
    """One decoded ``TrackFrame``: header, columns, and when this client received it."""

    key: str
    frame: TrackFrame
    tracks: TrackArrays
    received_ns: int  # this client's wall clock

    @property
    def sensor(self) -> str:
        return self.frame.sensor

    @property
    def schema_version(self) -> int:
        """1, 2 or 3; 2 and 3 carry ``tracks.covariance``, ``age_s`` and
        ``time_since_update_s``, 3 the ``epoch``."""
        return self.frame.schema_version


@dataclass(frozen=True, slots=True)
class VehicleTrackMessage(_TrackList):
    """One decoded ``VehicleTrackFrame``: a vehicle's fused track list at ``stamp_ns``
    (docs/VEHICLES.md, "One object list per vehicle"). ``seq`` is the vehicle stream's
    message counter."""

    key: str
    frame: VehicleTrackFrame
    tracks: TrackArrays  # with ``existence`` and ``sensor_stamp_ns`` (N, len(sensors))
    received_ns: int  # this client's wall clock

    @property
    def sensor(self) -> str:
        """The stream's name, ``@vehicle`` (the frame that produced it: ``source``)."""
        return VEHICLE_STREAM

    @property
    def source(self) -> tuple[str, int]:
        """(sensor, seq) of the input frame this message answers."""
        return self.frame.sensor, self.frame.sensor_seq

    @property
    def sensors(self) -> list[str]:
        return list(self.frame.sensors)

    @property
    def sensor_state(self) -> dict[str, SensorCondition]:
        """Each fused sensor's condition (ok, probation, silent, clock, extrinsic, unseen)."""
        return dict(zip(self.frame.sensors, self.frame.sensor_state, strict=True))

    @property
    def existence(self) -> npt.NDArray[np.float64]:
        assert self.tracks.existence is not None
        return self.tracks.existence

    def contributors(self, i: int) -> dict[str, int]:
        """The sensors that updated track i, each with the stamp of its last update."""
        stamps = self.tracks.sensor_stamp_ns
        assert stamps is not None
        return {s: int(t) for s, t in zip(self.frame.sensors, stamps[i].tolist(), strict=True)
                if t >= 0}  # fmt: skip


def tracks_key(prefix: str = "fleet", vehicle: str = "*", sensor: str = "*") -> str:
    """``<prefix>/<vehicle>/<sensor>/tracks``; ``*`` selects every vehicle or sensor."""
    for kind, value in (("vehicle", vehicle), ("sensor", sensor)):
        if value != "*":
            check_name(kind, value)
    return Keys(prefix).tracks(vehicle, sensor)


M = TypeVar("M", TrackMessage, VehicleTrackMessage)


class _Subscription(Generic[M]):
    """What both subscribers share: decoding on Zenoh's thread into a bounded buffer, exact
    repeats (a takeover's at-least-once) and a fenced holder's messages dropped, invalid
    payloads counted and logged."""

    def __init__(
        self,
        session: zenoh.Session,
        key_expr: str,
        callback: Callable[[M], None] | None,
        buffer: int,
        on_invalid: Callable[[str, Rejection], None] | None,
    ) -> None:
        self.key_expr = key_expr
        self.invalid = 0  # payloads on a tracks key that did not decode
        self._invalid_seen = 0  # the same, counted as each arrives (for the log line)
        self._invalid_lock = threading.Lock()
        self._filter = StreamFilter()
        self.invalid_reasons: dict[str, int] = {}  # the same, by ErrorReason value
        self.last_rejection: Rejection | None = None
        self._on_invalid = on_invalid
        self._invalid_logged_at = -INVALID_LOG_INTERVAL_S
        self._invalid_unlogged = 0
        self._session = session
        self._owns_session = False
        self._callback: Callable[[M], None] | None = callback
        self._mailbox: Mailbox[M] = Mailbox(buffer)
        self._closed = False
        self._sub = session.declare_subscriber(self.key_expr, self._on_sample)
        close_before_thread_join(self)

    @classmethod
    def connect(cls, *, options: ZenohOptions | None = None, **kwargs: Any) -> Self:
        """A subscriber with a session of its own (closed by ``close()``). Without options it
        joins a service on this machine: peer mode, connecting to ``tcp/127.0.0.1:7447``."""
        session = open_session(options or default_options())
        try:
            sub = cls(session, **kwargs)
        except BaseException:
            session.close()  # type: ignore[no-untyped-call]
            raise
        sub._owns_session = True
        return sub

    def _decode(self, key: str, payload: bytes, received_ns: int) -> M | Rejection:
        raise NotImplementedError

    def _on_sample(self, sample: zenoh.Sample) -> None:
        received = time.time_ns()
        key = str(sample.key_expr)
        msg = self._decode(key, sample.payload.to_bytes(), received)
        if isinstance(msg, Rejection):
            self._invalid(key, msg)
            return
        if self._filter.admit(key, msg.seq, msg.stamp_ns, msg.epoch) is not Verdict.DELIVER:
            return
        if self._callback is None:
            self._mailbox.put(msg)
            return
        try:
            self._callback(msg)
        except Exception:  # a user callback must not kill Zenoh's thread
            log.exception("track callback failed")

    def _invalid(self, key: str, r: Rejection) -> None:
        with self._invalid_lock:  # samples of two links come on two threads
            self._invalid_seen += 1
            self.invalid_reasons[r.reason.value] = self.invalid_reasons.get(r.reason.value, 0) + 1
            self.last_rejection = r
            now = time.monotonic()
            if now - self._invalid_logged_at >= INVALID_LOG_INTERVAL_S:
                log.warning(
                    "invalid track frame on %s: %s (field %s): %s; %d invalid so far, "
                    "%d more since the last line",
                    key,
                    r.reason.value,
                    r.field,
                    r.detail,
                    self._invalid_seen,
                    self._invalid_unlogged,
                    extra={"key": key, "reason": r.reason.value, "field": r.field},
                )
                self._invalid_logged_at, self._invalid_unlogged = now, 0
            else:
                self._invalid_unlogged += 1
        if self._on_invalid is not None:
            try:
                self._on_invalid(key, r)
            except Exception:  # a user callback must not kill Zenoh's thread
                log.exception("on_invalid callback failed")
        # Counted last: whoever sees the count also sees the log line and the callback's work
        # (a test that waited for the count once read the log before the line was written).
        with self._invalid_lock:
            self.invalid += 1

    # ----------------------------------------------------------------- consuming
    @property
    def duplicates(self) -> int:
        """Frames delivered before (same key, seq and stamp), not delivered again."""
        return self._filter.repeats

    @property
    def stale(self) -> int:
        """Frames of a fenced holder (an epoch below its stream's highest), not delivered."""
        return self._filter.stale

    @property
    def received(self) -> int:
        return self._mailbox.put_count

    @property
    def dropped(self) -> int:
        """Frames pushed out of the full buffer before anyone took them."""
        return self._mailbox.dropped

    def recv(self, timeout: float | None = None) -> M | None:
        """The next frame; None on timeout or once closed and drained."""
        return self._mailbox.get(timeout)

    def try_recv(self) -> M | None:
        return self._mailbox.get_nowait()

    def __iter__(self) -> Iterator[M]:
        return iter(self._mailbox)

    def __aiter__(self) -> AsyncIterator[M]:
        return self._mailbox.__aiter__()

    async def recv_async(self) -> M | None:
        return await self._mailbox.get_async()

    # ----------------------------------------------------------------- shutdown
    def close(self) -> None:
        """Wake every consumer and stop; closes the session if this subscriber opened it."""
        if self._closed:
            return
        self._closed = True
        self._mailbox.close()
        if self._owns_session:
            _close_quietly(self._session)
        else:
            with contextlib.suppress(Exception):  # already gone with its session
                self._sub.undeclare()  # type: ignore[no-untyped-call]

    def __enter__(self) -> Self:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    async def __aenter__(self) -> Self:
        return self

    async def __aexit__(self, *exc: object) -> None:
        self.close()


class TrackSubscriber(_Subscription[TrackMessage]):
    """Subscribes to sensors' tracks by key expression (default: the whole fleet under
    ``prefix``)."""

    def __init__(
        self,
        session: zenoh.Session,
        *,
        vehicle: str = "*",
        sensor: str = "*",
        prefix: str = "fleet",
        key_expr: str | None = None,
        callback: Callable[[TrackMessage], None] | None = None,
        buffer: int = 1024,
        on_invalid: Callable[[str, Rejection], None] | None = None,
    ) -> None:
        key = key_expr or tracks_key(prefix, vehicle, sensor)
        super().__init__(session, key, callback, buffer, on_invalid)

    def _decode(self, key: str, payload: bytes, received_ns: int) -> TrackMessage | Rejection:
        decoded = decode_track_frame(payload)
        if isinstance(decoded, Rejection):
            return decoded
        return TrackMessage(key, decoded[0], decoded[1], received_ns)


class VehicleTrackSubscriber(_Subscription[VehicleTrackMessage]):
    """Subscribes to fused vehicles' tracks, ``<prefix>/<vehicle>/@vehicle/tracks`` (every
    vehicle by default): one track list per vehicle, one id per object.

        with VehicleTrackSubscriber.connect(vehicle="veh01") as sub:
            for msg in sub:
                print(msg.seq, msg.global_ids, msg.existence, msg.contributors(0))
    """

    def __init__(
        self,
        session: zenoh.Session,
        *,
        vehicle: str = "*",
        prefix: str = "fleet",
        callback: Callable[[VehicleTrackMessage], None] | None = None,
        buffer: int = 1024,
        on_invalid: Callable[[str, Rejection], None] | None = None,
    ) -> None:
        if vehicle != "*":
            check_name("vehicle", vehicle)
        super().__init__(
            session, Keys(prefix).vehicle_tracks(vehicle), callback, buffer, on_invalid
        )

    def _decode(
        self, key: str, payload: bytes, received_ns: int
    ) -> VehicleTrackMessage | Rejection:
        decoded = decode_vehicle_track_frame(payload)
        if isinstance(decoded, Rejection):
            return decoded
        return VehicleTrackMessage(key, decoded[0], decoded[1], received_ns)
