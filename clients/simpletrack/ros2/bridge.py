"""The ROS 2 bridge process: Autoware DetectedObjects (CDR on a Zenoh key) in, detection frames
to the service, the service's tracks back out as Autoware TrackedObjects (CDR).

    with open_session(options) as session:
        bridge = Ros2Bridge(session, keys, vehicle="veh01", sensor="lidar", labels=labels,
                            classes=classes)
        bridge.run(stop)            # until stop is set; bridge.stats holds the counts
        bridge.close()

The Zenoh callback only queues the payload (a bounded queue: the oldest goes when full,
counted as ``dropped``); the caller's thread decodes, converts and publishes, so a slow
service never blocks Zenoh. Tracks are converted and put on the output key in the track
subscriber's callback.

Nothing a payload holds stops the bridge. A payload that is not a DetectedObjects is refused
(``bad_cdr``): counted, logged (the first of each reason, then at most once per
``log_interval_s`` with the count since) and announced as a ``malformed`` FrameError on the
sensor's errors key, where the service announces its own refusals. Objects left out of a frame
(``convert.Skip``) are counted and logged the same way; a label that maps to no class is
logged once per label. Frames the service refuses come back on the errors key: counted by
reason and logged.
"""

from __future__ import annotations

import contextlib
import logging
import threading
import time
from collections import Counter
from dataclasses import dataclass, field

import zenoh

from simpletrack.client.mailbox import Mailbox
from simpletrack.client.publisher import DetectionPublisher
from simpletrack.client.subscriber import TrackMessage, TrackSubscriber
from simpletrack.ros2.cdr import CdrError
from simpletrack.ros2.codec import decode_detected_objects, encode_tracked_objects
from simpletrack.ros2.convert import (
    ScoreSource,
    Skip,
    detections_to_boxes,
    tracks_to_tracked_objects,
)
from simpletrack.ros2.labels import LabelMap
from simpletrack.ros2.layout import Layout, TopicKeys, attachment, graph_tokens, publisher_gid
from simpletrack.session import Congestion
from simpletrack.wire import SCHEMA_VERSION, ErrorReason, FrameError, Rejection, encode
from simpletrack.wire.codec import decode_message
from simpletrack.wire.keys import Keys
from simpletrack.wire.messages import ServiceStatus

log = logging.getLogger("simpletrack.ros2.bridge")
CDR = zenoh.Encoding.APPLICATION_CDR
DEFAULT_LOG_INTERVAL_S = 10.0
DEFAULT_BUFFER = 64
BAD_CDR = "bad_cdr"
NOT_ENCODABLE = "not_encodable"


@dataclass
class BridgeStats:
    received: int = 0  # payloads on the input key
    published: int = 0  # detection frames sent to the service
    dropped: int = 0  # payloads pushed out of the full queue before conversion
    refused: Counter[str] = field(default_factory=Counter)  # frames the bridge could not send
    skipped: Counter[str] = field(default_factory=Counter)  # objects left out, by reason
    unknown_labels: Counter[int] = field(default_factory=Counter)
    service_errors: Counter[str] = field(default_factory=Counter)  # FrameErrors of the service
    tracks_in: int = 0  # track frames of the sensor from the service
    tracks_out: int = 0  # TrackedObjects put on the output key

    def summary(self) -> str:
        def counts(c: Counter[str]) -> str:
            return " (" + ", ".join(f"{k} {v}" for k, v in sorted(c.items())) + ")" if c else ""

        return (
            f"{self.received} DetectedObjects received, {self.published} frames published, "
            f"{self.dropped} dropped, {sum(self.refused.values())} refused{counts(self.refused)}, "
            f"{sum(self.skipped.values())} objects left out{counts(self.skipped)}, "
            f"{sum(self.service_errors.values())} refused by the service"
            f"{counts(self.service_errors)}, {self.tracks_out} TrackedObjects sent"
        )


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
    data: bytes
    received_ns: int


class Ros2Bridge:
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
        self.vehicle, self.sensor = vehicle, sensor
        self.labels, self.classes, self.score = labels, classes, score
        self.instance = instance
        self.stats = BridgeStats()
        self._rate = RateLog(log_interval_s)
        self._logged_labels: set[int] = set()
        self._lock = threading.Lock()  # stats are written from two threads
        self._queue: Mailbox[_Payload] = Mailbox(buffer)
        self._session = session
        self._publisher = DetectionPublisher(
            session,
            vehicle,
            sensor,
            classes=classes,
            prefix=prefix,
            congestion=congestion,
            on_error=self._on_service_error,
        )
        self._errors_pub = session.declare_publisher(Keys(prefix).errors(vehicle, sensor))
        self._out = session.declare_publisher(
            keys.out_key, encoding=CDR, congestion_control=zenoh.CongestionControl.BLOCK
        )
        self._out_seq = 0
        self._gid = publisher_gid(keys.out_key, instance)
        self._tokens: list[zenoh.LivelinessToken] = []
        if keys.layout is Layout.RMW_ZENOH:
            zid = str(session.info.zid())
            for token in graph_tokens(keys, zid):
                self._tokens.append(session.liveliness().declare_token(token))
        self._tracks = TrackSubscriber(
            session, vehicle=vehicle, sensor=sensor, prefix=prefix, callback=self._on_tracks
        )
        self._in = session.declare_subscriber(keys.in_key, self._on_sample)
        self._closed = False

    # ----------------------------------------------------------------- input
    def _on_sample(self, sample: zenoh.Sample) -> None:
        self._queue.put(_Payload(sample.payload.to_bytes(), time.time_ns()))

    def run(self, stop: threading.Event, poll_s: float = 0.1) -> None:
        """Convert and publish queued payloads until ``stop`` is set."""
        while not stop.is_set():
            item = self._queue.get(timeout=poll_s)
            if item is not None:
                self.handle(item.data, item.received_ns)

    def handle(self, payload: bytes, received_ns: int | None = None) -> int | None:
        """One DetectedObjects payload; returns the published frame's seq, None if refused."""
        with self._lock:
            self.stats.received += 1
            self.stats.dropped = self._queue.dropped
        try:
            msg = decode_detected_objects(payload)
        except CdrError as e:
            self._refuse(BAD_CDR, f"not a DetectedObjects CDR: {e}", received_ns)
            return None
        converted = detections_to_boxes(msg, self.labels, self.classes, self.score)
        self._note_skipped(converted.skipped, converted.unknown_labels)
        self._publisher.frame_id = converted.frame_id or self.sensor
        try:
            seq = self._publisher.publish_arrays(converted.boxes, stamp_ns=converted.stamp_ns)
        except ValueError as e:  # the encoder's refusal: e.g. a stamp before 1970
            self._refuse(NOT_ENCODABLE, f"cannot encode the frame: {e}", received_ns)
            return None
        with self._lock:
            self.stats.published += 1
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

    def _refuse(self, reason: str, detail: str, received_ns: int | None) -> None:
        with self._lock:
            self.stats.refused[reason] += 1
            total = self.stats.refused[reason]
        self._rate.warn(
            reason, "frame refused on %s: %s (%d so far)", self.keys.in_key, detail, total
        )
        error = FrameError(
            schema_version=SCHEMA_VERSION,
            vehicle=self.vehicle,
            sensor=self.sensor,
            reason=ErrorReason.MALFORMED if reason == BAD_CDR else ErrorReason.INVALID_VALUE,
            field="payload",
            detail=detail[:500],
            instance=self.instance,
            received_ns=received_ns or time.time_ns(),
        )
        try:
            self._errors_pub.put(encode(error))
        except zenoh.ZError as e:
            log.warning("could not announce a refusal on the errors key: %s", e)

    def _on_service_error(self, err: FrameError) -> None:
        if err.instance == self.instance:
            return  # our own announcement, heard back
        with self._lock:
            self.stats.service_errors[err.reason.value] += 1
        self._rate.warn(
            f"service:{err.reason.value}",
            "the service refused frame %s: %s (%s)",
            err.seq,
            err.reason.value,
            err.detail,
        )

    # ----------------------------------------------------------------- output
    def _on_tracks(self, msg: TrackMessage) -> None:
        with self._lock:
            self.stats.tracks_in += 1
        tracked = tracks_to_tracked_objects(
            msg.tracks,
            vehicle=self.vehicle,
            sensor=self.sensor,
            stamp_ns=msg.stamp_ns,
            frame_id=msg.frame.frame_id,
            labels=self.labels,
        )
        payload = encode_tracked_objects(tracked)
        if self.keys.layout is Layout.RMW_ZENOH:
            self._out_seq += 1  # one callback thread: no lock needed
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
            self._in,
            self._out,
            self._errors_pub,
            *self._tokens,
        ]
        for entity in entities:
            with contextlib.suppress(zenoh.ZError):  # gone with its session
                entity.undeclare()  # type: ignore[no-untyped-call]
        self._tracks.close()
        self._publisher.close()


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
