"""What the service puts on a sensor's keys: its track frames and its ``FrameError`` notices.
The one builder of a ``FrameError`` lives here, for the workers and for the shutdown path."""

from __future__ import annotations

import contextlib
import time

import zenoh

from simpletrack.server.logs import get_logger
from simpletrack.session import Congestion
from simpletrack.wire.codec import Rejection
from simpletrack.wire.codec import encode as encode_message
from simpletrack.wire.header import peek_header
from simpletrack.wire.keys import VEHICLE_STREAM, Keys
from simpletrack.wire.models import FrameError
from simpletrack.wire.reasons import SCHEMA_VERSION, ErrorReason

# The frame lines have always come from this logger (docs/SERVICE.md shows simpletrack.pool).
log = get_logger("pool")
MSGPACK = zenoh.Encoding("application/msgpack")

DROP_DETAILS = {
    ErrorReason.DROPPED_QUEUE_FULL: "worker queue full (backpressure drop_oldest)",
    ErrorReason.DROPPED_SHUTDOWN: "service shutting down",
    ErrorReason.MISSED: "recovered frames past the member's burst_bytes budget",
}


def congestion_control(setting: Congestion) -> zenoh.CongestionControl:
    if setting is Congestion.BLOCK:
        return zenoh.CongestionControl.BLOCK
    return zenoh.CongestionControl.DROP


def dropped(reason: ErrorReason, payload: bytes) -> Rejection:
    """The refusal of a frame shed under load: only its header is read."""
    seq, stamp_ns = peek_header(payload)
    return Rejection(reason, None, DROP_DETAILS.get(reason, reason.value), seq, stamp_ns)


def frame_error(
    vehicle: str,
    sensor: str,
    r: Rejection,
    instance: str,
    received_ns: int,
    seqs: list[int | None] | None = None,
) -> FrameError:
    return FrameError(
        schema_version=SCHEMA_VERSION,
        vehicle=vehicle,
        sensor=sensor,
        seq=r.seq,
        stamp_ns=r.stamp_ns,
        reason=r.reason,
        field=None if r.field is None else r.field[:256],
        detail=r.detail[:1024],
        instance=instance,
        received_ns=received_ns,
        seqs=seqs,
    )


def missed_notice(vehicle: str, sensor: str, detail: str, instance: str) -> FrameError:
    """A notice of frames no member will ever see (lost in transport, or in a takeover's gap)."""
    return FrameError(
        schema_version=SCHEMA_VERSION,
        vehicle=vehicle,
        sensor=sensor,
        reason=ErrorReason.MISSED,
        detail=detail[:1024],
        instance=instance,
        received_ns=time.time_ns(),
    )


def drop_notice(reason: ErrorReason, seqs: list[int | None], stamp_ns: int | None) -> Rejection:
    """The refusal standing for frames shed together: ``seq``/``stamp_ns`` are the first's."""
    n = len(seqs)
    what = DROP_DETAILS.get(reason, reason.value)
    # A missed notice always starts with its count, as the takeover's and the outage's do.
    detail = what if n == 1 and reason is not ErrorReason.MISSED else f"{n} frames: {what}"
    return Rejection(reason, None, detail, seqs[0], stamp_ns)


def put(
    session: zenoh.Session, key: str, payload: bytes, congestion: zenoh.CongestionControl
) -> None:
    session.put(key, payload, encoding=MSGPACK, congestion_control=congestion)


class Outbox:
    """One worker's publishers, declared on a sensor's first frame and kept until the sensor
    is forgotten. Only the worker's own thread uses it."""

    def __init__(
        self,
        session: zenoh.Session,
        keys: Keys,
        congestion: zenoh.CongestionControl,
        instance: str,
    ) -> None:
        self.session, self.keys, self.congestion, self.instance = (
            session,
            keys,
            congestion,
            instance,
        )
        self._tracks: dict[tuple[str, str], zenoh.Publisher] = {}
        # (vehicle, stream) -> its last tracks message: a fence stashes it with the state
        self.last: dict[tuple[str, str], bytes] = {}
        self._errors: dict[tuple[str, str], zenoh.Publisher] = {}

    def _publisher(
        self, table: dict[tuple[str, str], zenoh.Publisher], key: str, name: tuple[str, str]
    ) -> zenoh.Publisher:
        pub = table.get(name)
        if pub is None:
            pub = table[name] = self.session.declare_publisher(
                key, encoding=MSGPACK, congestion_control=self.congestion
            )
        return pub

    def tracks(self, vehicle: str, sensor: str, payload: bytes) -> None:
        key = self.keys.tracks(vehicle, sensor)
        self._publisher(self._tracks, key, (vehicle, sensor)).put(payload)
        self.last[(vehicle, sensor)] = payload

    def vehicle_tracks(self, vehicle: str, payload: bytes) -> None:
        """A fused vehicle's tracks (``<prefix>/<vehicle>/@vehicle/tracks``)."""
        key = self.keys.vehicle_tracks(vehicle)
        self._publisher(self._tracks, key, (vehicle, VEHICLE_STREAM)).put(payload)
        self.last[(vehicle, VEHICLE_STREAM)] = payload

    def resend(self, vehicle: str, sensor: str, payload: bytes) -> None:
        """A stream's last message again (at least once: a fence may have cut it off)."""
        if sensor == VEHICLE_STREAM:
            self.vehicle_tracks(vehicle, payload)
        else:
            self.tracks(vehicle, sensor, payload)

    def refuse(self, vehicle: str, sensor: str, r: Rejection, received_ns: int, held: bool) -> None:
        """Publish and log a refusal. ``held``: the sensor is one the worker holds (it gets a
        declared publisher); a sensor that never got in is told by a one-off put."""
        err = frame_error(vehicle, sensor, r, self.instance, received_ns)
        self._publish(err, held)
        log.warning(
            "frame_dropped" if r.reason.value.startswith("dropped") else "frame_rejected",
            vehicle=vehicle,
            sensor=sensor,
            seq=r.seq,
            reason=r.reason.value,
            field=r.field,
            detail=r.detail,
        )

    def drops(
        self,
        vehicle: str,
        sensor: str,
        reason: ErrorReason,
        seqs: list[int | None],
        stamp_ns: int | None,
        received_ns: int,
        held: bool,
    ) -> None:
        """Publish and log one notice naming every frame in ``seqs`` (shed under load)."""
        r = drop_notice(reason, seqs, stamp_ns)
        self._publish(frame_error(vehicle, sensor, r, self.instance, received_ns, seqs), held)
        log.warning(
            "frame_dropped",
            vehicle=vehicle,
            sensor=sensor,
            seq=r.seq,
            reason=reason.value,
            frames=len(seqs),
            last_seq=seqs[-1],
            detail=r.detail,
        )

    def notice(self, err: FrameError) -> None:
        """Publish a notice built elsewhere (frames missed at a takeover)."""
        self._publish(err, held=True)

    def _publish(self, err: FrameError, held: bool) -> None:
        vehicle, sensor = err.vehicle, err.sensor
        payload = encode_message(err)
        key = self.keys.errors(vehicle, sensor)
        try:
            if held:
                self._publisher(self._errors, key, (vehicle, sensor)).put(payload)
            else:
                put(self.session, key, payload, self.congestion)
        except zenoh.ZError as e:
            log.error(
                "error_publish_failed", vehicle=vehicle, sensor=sensor, seq=err.seq, error=str(e)
            )

    def forget(self, vehicle: str, sensor: str) -> None:
        """Undeclare a sensor's publishers (evicted, or the worker is stopping)."""
        self.last.pop((vehicle, sensor), None)
        for table in (self._tracks, self._errors):
            pub = table.pop((vehicle, sensor), None)
            if pub is not None:
                with contextlib.suppress(zenoh.ZError):  # session already closed
                    pub.undeclare()  # type: ignore[no-untyped-call]

    def close(self) -> None:
        for name in list(self._tracks.keys() | self._errors.keys()):
            self.forget(*name)
