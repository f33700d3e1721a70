"""The ROS 2 bridge process: Autoware DetectedObjects (CDR on a Zenoh key) in, detection frames
to the service, the service's tracks back out as Autoware TrackedObjects (CDR).

    with open_session(options) as session:
        bridge = Ros2Bridge(session, keys, vehicle="veh01", sensor="lidar", labels=labels,
                            classes=classes)
        bridge.run(stop)            # until stop is set; bridge.stats holds the counts
        bridge.close()

A fused vehicle (docs/SERVICE.md, "Vehicle fusion") has one bridge for all its sensors,
``FusedRos2Bridge``: one DetectedObjects input per sensor, each published as that sensor's
detection frames with the extrinsic (or pose) its ``header.frame_id`` has in the
``FrameTable`` (``frames``), and one TrackedObjects output of the vehicle's fused tracks
(``<prefix>/<vehicle>/@vehicle/tracks``).

The Zenoh callbacks only queue the payload (one bounded queue for every input, in arrival
order: the oldest goes when full, counted as ``dropped``); the caller's thread decodes,
converts and publishes, so a slow service never blocks Zenoh. Tracks are converted and put
on the output key in the track subscriber's callback.

Nothing a payload holds stops the bridge. A payload that is not a DetectedObjects is refused
(``bad_cdr``): counted, logged (the first of each reason, then at most once per
``log_interval_s`` with the count since) and announced as a ``malformed`` FrameError on the
sensor's errors key, where the service announces its own refusals; so is a fused input's
message in a frame the bridge has no transform for (``unknown_frame``, announced as
``missing_field``). Objects left out of a frame (``convert.Skip``) are counted and logged the
same way; a label that maps to no class is logged once per label. Frames the service refuses
come back on the errors key: counted by reason and logged.
"""

from __future__ import annotations

import contextlib
import logging
import threading
import time
from collections import Counter
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

import zenoh

from simpletrack.client.mailbox import Mailbox
from simpletrack.client.publisher import DetectionPublisher
from simpletrack.client.subscriber import (
    TrackMessage,
    TrackSubscriber,
    VehicleTrackMessage,
    VehicleTrackSubscriber,
)
from simpletrack.ros2.cdr import CdrError
from simpletrack.ros2.codec import decode_detected_objects, encode_tracked_objects
from simpletrack.ros2.convert import (
    Converted,
    ScoreSource,
    Skip,
    detections_to_boxes,
    tracks_to_tracked_objects,
)
from simpletrack.ros2.frames import FrameMode, FrameTable, Placement
from simpletrack.ros2.labels import LabelMap
from simpletrack.ros2.layout import (
    FusedKeys,
    Layout,
    TopicKeys,
    attachment,
    graph_tokens,
    publisher_gid,
)
from simpletrack.ros2.messages import TrackedObjects
from simpletrack.session import Congestion
from simpletrack.wire import SCHEMA_VERSION, ErrorReason, FrameError, Rejection, encode
from simpletrack.wire.codec import decode_message
from simpletrack.wire.keys import VEHICLE_STREAM, Keys
from simpletrack.wire.messages import ServiceStatus

log = logging.getLogger("simpletrack.ros2.bridge")
CDR = zenoh.Encoding.APPLICATION_CDR
DEFAULT_LOG_INTERVAL_S = 10.0
DEFAULT_BUFFER = 64
BAD_CDR = "bad_cdr"
NOT_ENCODABLE = "not_encodable"
UNKNOWN_FRAME = "unknown_frame"


def _counts(c: Counter[str]) -> str:
    return " (" + ", ".join(f"{k} {v}" for k, v in sorted(c.items())) + ")" if c else ""


@dataclass
class InputStats:
    """One input of a fused vehicle's bridge."""

    received: int = 0
    published: int = 0
    refused: Counter[str] = field(default_factory=Counter)
    service_errors: Counter[str] = field(default_factory=Counter)

    def summary(self) -> str:
        return (
            f"{self.received} received, {self.published} published, "
            f"{sum(self.refused.values())} refused{_counts(self.refused)}, "
            f"{sum(self.service_errors.values())} refused by the service"
            f"{_counts(self.service_errors)}"
        )


@dataclass
class BridgeStats:
    received: int = 0  # payloads on the input keys
    published: int = 0  # detection frames sent to the service
    dropped: int = 0  # payloads pushed out of the full queue before conversion
    refused: Counter[str] = field(default_factory=Counter)  # frames the bridge could not send
    skipped: Counter[str] = field(default_factory=Counter)  # objects left out, by reason
    unknown_labels: Counter[int] = field(default_factory=Counter)
    service_errors: Counter[str] = field(default_factory=Counter)  # FrameErrors of the service
    tracks_in: int = 0  # track frames of the sensor (or fused vehicle) from the service
    tracks_out: int = 0  # TrackedObjects put on the output key
    inputs: dict[str, InputStats] = field(default_factory=dict)  # by sensor
    fused: bool = False  # the summary then gives each input's counts too

    def summary(self) -> str:
        line = (
            f"{self.received} DetectedObjects received, {self.published} frames published, "
            f"{self.dropped} dropped, {sum(self.refused.values())} refused"
            f"{_counts(self.refused)}, "
            f"{sum(self.skipped.values())} objects left out{_counts(self.skipped)}, "
            f"{sum(self.service_errors.values())} refused by the service"
            f"{_counts(self.service_errors)}, {self.tracks_out} TrackedObjects sent"
        )
        if self.fused:
            line += "; " + "; ".join(f"{s}: {i.summary()}" for s, i in self.inputs.items())
        return line


class RateLog:
    """Logs the first occurrence of each reason, then at most once per ``interval_s`` with the
    count of occurrences since the last line."""

    def __init__(self, interval_s: float) -> None:
        self.interval_s = interval_s
        self._last: dict[str, float] = {}
        self._since: Counter[str] = Counter()
        self._lock = threading.Lock()

    def warn(self, reason: str, message: str, *args: object) -> None:
        now = time.monotonic()
        with self._lock:
            last = self._last.get(reason)
            if last is not None and now - last < self.interval_s:
                self._since[reason] += 1
                return
            unlogged = self._since.pop(reason, 0)
            self._last[reason] = now
        suffix = f" ({unlogged} more since the last line)" if unlogged else ""
        log.warning(message + suffix, *args)


@dataclass(frozen=True, slots=True)
class _Payload:
    sensor: str
    data: bytes
    received_ns: int


@dataclass(frozen=True, slots=True)
class _Input:
    """One DetectedObjects input: its key, its sensor's publisher and errors key."""

    sensor: str
    key: str
    publisher: DetectionPublisher
    errors: zenoh.Publisher


@dataclass(frozen=True, slots=True)
class _Refusal:
    reason: str  # the bridge's count
    error: ErrorReason  # what the FrameError says
    field: str
    detail: str


class _Bridge:
    """What both bridges share: inputs queued by the Zenoh callbacks and converted on the
    caller's thread, refusals counted, logged and announced, the TrackedObjects output."""

    def __init__(
        self,
        session: zenoh.Session,
        *,
        layout: Layout,
        inputs: Sequence[tuple[str, str]],  # (sensor, key)
        out_key: str,
        tokens: Callable[[str], list[str]],  # zid -> rmw_zenoh graph tokens
        vehicle: str,
        labels: LabelMap,
        classes: tuple[str, ...],
        prefix: str,
        score: ScoreSource,
        instance: str,
        buffer: int,
        congestion: Congestion,
        log_interval_s: float,
        fused: bool,
    ) -> None:
        self.vehicle = vehicle
        self.labels, self.classes, self.score = labels, classes, score
        self.instance = instance
        self.stats = BridgeStats(fused=fused)
        self._layout = layout
        self._rate = RateLog(log_interval_s)
        self._logged_labels: set[int] = set()
        self._lock = threading.Lock()  # stats are written from several threads
        self._queue: Mailbox[_Payload] = Mailbox(buffer)
        self._session = session
        self._inputs: dict[str, _Input] = {}
        for sensor, key in inputs:
            publisher = DetectionPublisher(
                session,
                vehicle,
                sensor,
                classes=classes,
                prefix=prefix,
                congestion=congestion,
                on_error=self._on_service_error,
            )
            errors = session.declare_publisher(Keys(prefix).errors(vehicle, sensor))
            self._inputs[sensor] = _Input(sensor, key, publisher, errors)
            self.stats.inputs[sensor] = InputStats()
        self._out = session.declare_publisher(
            out_key, encoding=CDR, congestion_control=zenoh.CongestionControl.BLOCK
        )
        self._out_seq = 0
        self._gid = publisher_gid(out_key, instance)
        self._tokens: list[zenoh.LivelinessToken] = []
        if layout is Layout.RMW_ZENOH:
            for token in tokens(str(session.info.zid())):
                self._tokens.append(session.liveliness().declare_token(token))
        self._tracks = self._declare_tracks(session, prefix)
        self._subs = [
            session.declare_subscriber(i.key, self._on_sample_of(i.sensor))
            for i in self._inputs.values()
        ]
        self._closed = False

    def _declare_tracks(
        self, session: zenoh.Session, prefix: str
    ) -> TrackSubscriber | VehicleTrackSubscriber:
        raise NotImplementedError

    def _place(self, inp: _Input, converted: Converted) -> Placement | _Refusal:
        """What goes with the frame's boxes (extrinsic or pose), or why it cannot go."""
        raise NotImplementedError

    # ----------------------------------------------------------------- input
    def _on_sample_of(self, sensor: str) -> Callable[[zenoh.Sample], None]:
        def on_sample(sample: zenoh.Sample) -> None:
            self._queue.put(_Payload(sensor, sample.payload.to_bytes(), time.time_ns()))

        return on_sample

    def run(self, stop: threading.Event, poll_s: float = 0.1) -> None:
        """Convert and publish queued payloads until ``stop`` is set."""
        while not stop.is_set():
            item = self._queue.get(timeout=poll_s)
            if item is not None:
                self.handle(item.data, item.received_ns, sensor=item.sensor)

    def handle(
        self, payload: bytes, received_ns: int | None = None, *, sensor: str | None = None
    ) -> int | None:
        """One DetectedObjects payload of ``sensor``'s input (default: the only one); returns
        the published frame's seq, None if refused."""
        if sensor is None:
            if len(self._inputs) != 1:
                raise ValueError(f"which input? {', '.join(self._inputs)}")
            sensor = next(iter(self._inputs))
        inp = self._inputs[sensor]
        with self._lock:
            self.stats.received += 1
            self.stats.inputs[sensor].received += 1
            self.stats.dropped = self._queue.dropped
        try:
            msg = decode_detected_objects(payload)
        except CdrError as e:
            refusal = _Refusal(
                BAD_CDR, ErrorReason.MALFORMED, "payload", f"not a DetectedObjects CDR: {e}"
            )
            self._refuse(inp, refusal, received_ns)
            return None
        converted = detections_to_boxes(msg, self.labels, self.classes, self.score)
        self._note_skipped(converted.skipped, converted.unknown_labels)
        placement = self._place(inp, converted)
        if isinstance(placement, _Refusal):
            self._refuse(inp, placement, received_ns)
            return None
        inp.publisher.frame_id = converted.frame_id or sensor
        try:
            seq = inp.publisher.publish_arrays(
                converted.boxes,
                stamp_ns=converted.stamp_ns,
                pose=placement.pose,
                extrinsic=placement.extrinsic,
            )
        except ValueError as e:  # the encoder's refusal: e.g. a stamp before 1970
            refusal = _Refusal(
                NOT_ENCODABLE, ErrorReason.INVALID_VALUE, "payload", f"cannot encode the frame: {e}"
            )
            self._refuse(inp, refusal, received_ns)
            return None
        with self._lock:
            self.stats.published += 1
            self.stats.inputs[sensor].published += 1
        return seq

    def _note_skipped(self, skipped: Counter[Skip], unknown: Counter[int]) -> None:
        with self._lock:
            self.stats.skipped.update(skipped)
            self.stats.unknown_labels.update(unknown)
        for reason, n in skipped.items():
            if reason is not Skip.UNKNOWN_LABEL:
                self._rate.warn(reason, "objects left out of a frame: %s (%d)", reason, n)
        for label in unknown:
            if label not in self._logged_labels:
                self._logged_labels.add(label)
                log.warning(
                    "label %d maps to no class of the service (%s: %s): objects with it are "
                    "left out and counted; --labels changes the map",
                    label,
                    self.labels.name,
                    self.labels.describe(),
                )

    def _refuse(self, inp: _Input, refusal: _Refusal, received_ns: int | None) -> None:
        with self._lock:
            self.stats.refused[refusal.reason] += 1
            self.stats.inputs[inp.sensor].refused[refusal.reason] += 1
            total = self.stats.inputs[inp.sensor].refused[refusal.reason]
        self._rate.warn(
            f"{inp.sensor}:{refusal.reason}",
            "frame refused on %s: %s (%d so far)",
            inp.key,
            refusal.detail,
            total,
        )
        error = FrameError(
            schema_version=SCHEMA_VERSION,
            vehicle=self.vehicle,
            sensor=inp.sensor,
            reason=refusal.error,
            field=refusal.field,
            detail=refusal.detail[:500],
            instance=self.instance,
            received_ns=received_ns or time.time_ns(),
        )
        try:
            inp.errors.put(encode(error))
        except zenoh.ZError as e:
            log.warning("could not announce a refusal on the errors key: %s", e)

    def _on_service_error(self, err: FrameError) -> None:
        if err.instance == self.instance:
            return  # our own announcement, heard back
        with self._lock:
            self.stats.service_errors[err.reason.value] += 1
            if err.sensor in self.stats.inputs:
                self.stats.inputs[err.sensor].service_errors[err.reason.value] += 1
        self._rate.warn(
            f"service:{err.sensor}:{err.reason.value}",
            "the service refused frame %s of %s: %s (%s)",
            err.seq,
            err.sensor,
            err.reason.value,
            err.detail,
        )

    # ----------------------------------------------------------------- output
    def _put_tracked(self, tracked: TrackedObjects) -> None:
        """On the track subscriber's callback thread (one thread: no lock for the seq)."""
        payload = encode_tracked_objects(tracked)
        if self._layout is Layout.RMW_ZENOH:
            self._out_seq += 1
            extra = attachment(self._out_seq, time.time_ns(), self._gid)
            self._out.put(payload, attachment=extra)
        else:
            self._out.put(payload)
        with self._lock:
            self.stats.tracks_out += 1

    # ----------------------------------------------------------------- shutdown
    def close(self) -> None:
        if self._closed:
            return
        self._closed = True
        self._queue.close()
        self.stats.dropped = self._queue.dropped
        entities: list[zenoh.Subscriber[None] | zenoh.Publisher | zenoh.LivelinessToken] = [
            *self._subs,
            self._out,
            *(i.errors for i in self._inputs.values()),
            *self._tokens,
        ]
        for entity in entities:
            with contextlib.suppress(zenoh.ZError):  # gone with its session
                entity.undeclare()  # type: ignore[no-untyped-call]
        self._tracks.close()
        for inp in self._inputs.values():
            inp.publisher.close()


class Ros2Bridge(_Bridge):
    """One vehicle sensor: its DetectedObjects in, its own tracks (``TrackFrame``) out."""

    def __init__(
        self,
        session: zenoh.Session,
        keys: TopicKeys,
        *,
        vehicle: str,
        sensor: str,
        labels: LabelMap,
        classes: tuple[str, ...],
        prefix: str = "fleet",
        score: ScoreSource = ScoreSource.EXISTENCE,
        instance: str = "ros2-bridge",
        buffer: int = DEFAULT_BUFFER,
        congestion: Congestion = Congestion.BLOCK,
        log_interval_s: float = DEFAULT_LOG_INTERVAL_S,
    ) -> None:
        self.keys = keys
        self.sensor = sensor
        super().__init__(
            session,
            layout=keys.layout,
            inputs=[(sensor, keys.in_key)],
            out_key=keys.out_key,
            tokens=lambda zid: graph_tokens(keys, zid),
            vehicle=vehicle,
            labels=labels,
            classes=classes,
            prefix=prefix,
            score=score,
            instance=instance,
            buffer=buffer,
            congestion=congestion,
            log_interval_s=log_interval_s,
            fused=False,
        )

    def _declare_tracks(self, session: zenoh.Session, prefix: str) -> TrackSubscriber:
        return TrackSubscriber(
            session,
            vehicle=self.vehicle,
            sensor=self.sensor,
            prefix=prefix,
            callback=self._on_tracks,
        )

    def _place(self, inp: _Input, converted: Converted) -> Placement:
        return Placement()  # tracked in the detections' own frame, as it comes

    def _on_tracks(self, msg: TrackMessage) -> None:
        with self._lock:
            self.stats.tracks_in += 1
        self._put_tracked(
            tracks_to_tracked_objects(
                msg.tracks,
                vehicle=self.vehicle,
                sensor=self.sensor,
                stamp_ns=msg.stamp_ns,
                frame_id=msg.frame.frame_id,
                labels=self.labels,
            )
        )


class FusedRos2Bridge(_Bridge):
    """A fused vehicle: each sensor's DetectedObjects in (published as that sensor's frames,
    with the extrinsic or pose ``frames`` gives their ``header.frame_id``), the vehicle's fused
    tracks (``VehicleTrackFrame``) out as one TrackedObjects."""

    def __init__(
        self,
        session: zenoh.Session,
        keys: FusedKeys,
        *,
        vehicle: str,
        labels: LabelMap,
        classes: tuple[str, ...],
        frames: FrameTable | None = None,
        prefix: str = "fleet",
        score: ScoreSource = ScoreSource.EXISTENCE,
        instance: str = "ros2-bridge",
        buffer: int = DEFAULT_BUFFER,
        congestion: Congestion = Congestion.BLOCK,
        log_interval_s: float = DEFAULT_LOG_INTERVAL_S,
    ) -> None:
        self.keys = keys
        self.frames = frames or FrameTable()
        self._frame_warned = False
        super().__init__(
            session,
            layout=keys.layout,
            inputs=[(i.sensor, i.key) for i in keys.inputs],
            out_key=keys.out_key,
            tokens=lambda zid: graph_tokens(keys, zid),
            vehicle=vehicle,
            labels=labels,
            classes=classes,
            prefix=prefix,
            score=score,
            instance=instance,
            buffer=buffer,
            congestion=congestion,
            log_interval_s=log_interval_s,
            fused=True,
        )

    def _declare_tracks(self, session: zenoh.Session, prefix: str) -> VehicleTrackSubscriber:
        return VehicleTrackSubscriber(
            session, vehicle=self.vehicle, prefix=prefix, callback=self._on_vehicle_tracks
        )

    def _place(self, inp: _Input, converted: Converted) -> Placement | _Refusal:
        placement = self.frames.place(converted.frame_id)
        if placement is not None:
            return placement
        frame = converted.frame_id
        if self.frames.mode is FrameMode.WORLD:
            detail = (
                f"DetectedObjects in frame {frame!r}: this bridge sends world-frame objects "
                f"only ({self.frames.describe()}), with the identity pose"
            )
            return _Refusal(UNKNOWN_FRAME, ErrorReason.MISSING_FIELD, "pose", detail)
        detail = (
            f"DetectedObjects in frame {frame!r}: the bridge has no extrinsic for it (it knows "
            f"{self.frames.describe()}); give --extrinsic {frame or 'FRAME'}=<16 numbers, "
            "the frame->vehicle transform>"
        )
        return _Refusal(UNKNOWN_FRAME, ErrorReason.MISSING_FIELD, "extrinsic", detail)

    def _on_vehicle_tracks(self, msg: VehicleTrackMessage) -> None:
        with self._lock:
            self.stats.tracks_in += 1
        out_frame = self.frames.output_frame
        if msg.frame.frame_id != out_frame and not self._frame_warned:
            self._frame_warned = True
            log.warning(
                "the service names %s's fused frame %r; the bridge put every box in %r and "
                "publishes the tracks in %r: set the service's %s to %r to agree",
                self.vehicle,
                msg.frame.frame_id,
                out_frame,
                out_frame,
                "world_frame_id"
                if self.frames.mode is FrameMode.WORLD
                else "fusion.vehicle_frame_id",
                out_frame,
            )
        self._put_tracked(
            tracks_to_tracked_objects(
                msg.tracks,
                vehicle=self.vehicle,
                sensor=VEHICLE_STREAM,
                stamp_ns=msg.stamp_ns,
                frame_id=out_frame,
                labels=self.labels,
            )
        )


def service_status(session: zenoh.Session, prefix: str, timeout: float) -> ServiceStatus | None:
    """The status of the first service instance under ``prefix`` that answers within
    ``timeout``; asked again every second, since a session just opened may not have
    reached the service yet."""
    deadline = time.monotonic() + timeout
    while True:
        left = deadline - time.monotonic()
        if left <= 0:
            return None
        for reply in session.get(Keys(prefix).status("*"), timeout=min(1.0, left)):
            if reply.ok is None:
                continue
            status = decode_message(reply.ok.payload.to_bytes(), ServiceStatus)
            if not isinstance(status, Rejection):
                return status
        time.sleep(min(0.1, max(0.0, deadline - time.monotonic())))
