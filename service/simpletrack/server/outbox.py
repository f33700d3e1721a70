"""What the service puts on a sensor's keys: its track frames and its ``FrameError`` notices.
The one builder of a ``FrameError`` lives here, for the workers and for the shutdown path: the
light message of ``simpletrack.wire`` (no pydantic on a worker's refusal path), encoded by
``simpletrack.wire.codec.encode`` to the bytes the pydantic model always gave. The notices
are published by the member's announcer thread (server/announcer.py), never by a worker."""

from __future__ import annotations

import contextlib
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import zenoh

from simpletrack.server.logs import get_logger
from simpletrack.server.told import Teller
from simpletrack.session import Congestion
from simpletrack.wire.codec import Rejection
from simpletrack.wire.codec import encode as encode_message
from simpletrack.wire.header import peek_header
from simpletrack.wire.keys import VEHICLE_STREAM, Keys
from simpletrack.wire.messages import FrameError
from simpletrack.wire.reasons import SCHEMA_VERSION, ErrorReason

if TYPE_CHECKING:  # the announcer imports this module's constants
    from simpletrack.server.announcer import Announcer

# The frame lines have always come from this logger (docs/SERVICE.md shows simpletrack.pool).
log = get_logger("pool")
MSGPACK = zenoh.Encoding("application/msgpack")

# A sensor refusing frames by the thousand (a garbage flood) would cost the worker a log line
# each, a third of its time in such a flood: the first refusal of each sensor and reason is
# logged, then at most one line per REFUSAL_LOG_S (the latest, with how many were not logged
# since: ``repeated``). Every refusal is still announced on the errors key and counted.
REFUSAL_LOG_S = 10.0
_REFUSAL_LOG_CAP = 10_000  # sensors remembered; past it, forgotten (their next line is logged)

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
    """One worker's tracks publishers, declared on a sensor's first frame and kept until the
    sensor is forgotten, and its notices, handed to the member's announcer. Only the worker's
    own thread uses it."""

    def __init__(
        self,
        session: zenoh.Session,
        keys: Keys,
        congestion: zenoh.CongestionControl,
        instance: str,
        announcer: Announcer,
        standby_of: Callable[[str], str | None] | None = None,
    ) -> None:
        self.session, self.keys, self.congestion, self.instance = (
            session,
            keys,
            congestion,
            instance,
        )
        # Its sensors' standbys told of the messages out (none: a member alone, a test).
        self.teller = None if standby_of is None else Teller(self, standby_of)
        self.announcer = announcer
        self._tracks: dict[tuple[str, str], zenoh.Publisher] = {}
        # (vehicle, stream) -> its last tracks message: a fence stashes it with the state
        self.last: dict[tuple[str, str], bytes] = {}
        self._refusals = RepeatLog()

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
        """A sensor's tracks; behind its notices still waiting in the announcer, if any (a
        subscriber hears of the sensor's frames in the order they were answered)."""
        key = self.keys.tracks(vehicle, sensor)
        if self.announcer.behind(key, payload, (vehicle, sensor)):
            # The standby is told after the message is out (the announcer's order); a full
            # backlog leaves it untold: it then thinks planners have less, and a failover
            # publishes again what they had, never less (server/told.py).
            told = None if self.teller is None else self.teller.message(vehicle, sensor, payload)
            if told is not None:
                self.announcer.behind(*told, (vehicle, sensor))
        else:
            self._publisher(self._tracks, key, (vehicle, sensor)).put(payload)
            if self.teller is not None:
                self.teller.published(vehicle, sensor, payload)
        self.last[(vehicle, sensor)] = payload

    def vehicle_tracks(self, vehicle: str, payload: bytes) -> None:
        """A fused vehicle's tracks (``<prefix>/<vehicle>/@vehicle/tracks``)."""
        key = self.keys.vehicle_tracks(vehicle)
        self._publisher(self._tracks, key, (vehicle, VEHICLE_STREAM)).put(payload)
        if self.teller is not None:
            self.teller.published(vehicle, VEHICLE_STREAM, payload)
        self.last[(vehicle, VEHICLE_STREAM)] = payload

    def resend(self, vehicle: str, sensor: str, payload: bytes) -> None:
        """A stream's last message again (at least once: a fence may have cut it off)."""
        if sensor == VEHICLE_STREAM:
            self.vehicle_tracks(vehicle, payload)
        else:
            self.tracks(vehicle, sensor, payload)

    def refuse(self, vehicle: str, sensor: str, r: Rejection, received_ns: int) -> None:
        """Announce and log a refusal (the log at most once per REFUSAL_LOG_S per sensor and
        reason after the first). ValueError for a notice that cannot be encoded."""
        self._publish(frame_error(vehicle, sensor, r, self.instance, received_ns))
        fields: dict[str, Any] = {
            "vehicle": vehicle,
            "sensor": sensor,
            "seq": r.seq,
            "reason": r.reason.value,
            "field": r.field,
            "detail": r.detail,
        }
        if r.reason.value.startswith("dropped"):  # the log names every frame shed (their count)
            log.warning("frame_dropped", **fields)
            return
        repeated = self._refusals.admit((vehicle, sensor), r.reason.value, fields)
        if repeated is not None:
            log.warning("frame_rejected", **fields, **({"repeated": repeated} if repeated else {}))

    def flush_logs(self) -> None:
        """Log the latest refusal of each sensor and reason whose interval has passed with
        refusals not logged (a flood that stopped still gets its count into the log), and
        the announcer's notices dropped since its last line."""
        for fields, repeated in self._refusals.due():
            log.warning("frame_rejected", **fields, repeated=repeated)
        self.announcer.flush_logs()

    def drops(
        self,
        vehicle: str,
        sensor: str,
        reason: ErrorReason,
        seqs: list[int | None],
        stamp_ns: int | None,
        received_ns: int,
    ) -> None:
        """Announce and log one notice naming every frame in ``seqs`` (shed under load)."""
        r = drop_notice(reason, seqs, stamp_ns)
        self._publish(frame_error(vehicle, sensor, r, self.instance, received_ns, seqs))
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
        """Announce a notice built elsewhere (frames missed at a takeover)."""
        self._publish(err)

    def _publish(self, err: FrameError) -> None:
        """Encode here (ValueError for a notice the decoders would refuse); the announcer
        publishes it (counted and logged there should its backlog be full)."""
        vehicle, sensor = err.vehicle, err.sensor
        payload = encode_message(err)
        self.announcer.announce(self.keys.errors(vehicle, sensor), payload, (vehicle, sensor))

    def forget(self, vehicle: str, sensor: str) -> None:
        """Undeclare a sensor's publisher (evicted, or the worker is stopping)."""
        self.last.pop((vehicle, sensor), None)
        self._refusals.forget((vehicle, sensor))
        pub = self._tracks.pop((vehicle, sensor), None)
        if pub is not None:
            with contextlib.suppress(zenoh.ZError):  # session already closed
                pub.undeclare()  # type: ignore[no-untyped-call]

    def close(self) -> None:
        for name in list(self._tracks):
            self.forget(*name)
        if self.teller is not None:
            self.teller.close()


Logged = dict[str, Any]  # a refusal's log fields


@dataclass(slots=True)
class _Repeats:
    next_at: float  # when the next line may be logged
    held: int = 0  # refusals not logged since the last line
    latest: Logged | None = None  # the latest of them


class RepeatLog:
    """Which refusals to log: per (sensor, reason), the first, then the latest once
    ``interval_s`` has passed since the last line logged. ``admit`` says None (not now) or how
    many were not logged since that line; ``due`` gives the held-back latest ones whose
    interval has passed. Pure but for the clock it is given."""

    def __init__(
        self,
        interval_s: float = REFUSAL_LOG_S,
        cap: int = _REFUSAL_LOG_CAP,
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        self.interval_s, self.cap, self._clock = interval_s, cap, clock
        self._by_sensor: dict[tuple[str, str], dict[str, _Repeats]] = {}

    def admit(self, sensor: tuple[str, str], reason: str, latest: Logged) -> int | None:
        now = self._clock()
        reasons = self._by_sensor.get(sensor)
        if reasons is None:
            if len(self._by_sensor) >= self.cap:
                self._by_sensor.clear()  # sensor names come from the fleet: bounded memory
            reasons = self._by_sensor[sensor] = {}
        entry = reasons.get(reason)
        if entry is None:
            reasons[reason] = _Repeats(now + self.interval_s)
            return 0
        if now >= entry.next_at:
            repeated = entry.held
            reasons[reason] = _Repeats(now + self.interval_s)
            return repeated
        entry.held += 1
        entry.latest = latest
        return None

    def due(self) -> list[tuple[Logged, int]]:
        """The held-back latest refusal of each sensor and reason whose interval has passed,
        with how many others were not logged before it; they count as logged now."""
        now = self._clock()
        out: list[tuple[Logged, int]] = []
        for reasons in self._by_sensor.values():
            for reason, entry in reasons.items():
                if entry.latest is not None and now >= entry.next_at:
                    out.append((entry.latest, entry.held - 1))
                    reasons[reason] = _Repeats(now + self.interval_s)
        return out

    def forget(self, sensor: tuple[str, str]) -> None:
        self._by_sensor.pop(sensor, None)
