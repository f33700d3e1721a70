"""Frames lost in transport: the advanced subscriber recovers what it can from a vehicle's
cache; what it cannot is counted per sensor and announced on the sensor's errors key.

The notice goes through the member's announcer, like the workers' refusals: published with
the ``congestion_control`` setting from the announcer's thread, so a miss listener (Zenoh's
own thread) never waits, and the sensor's tracks of the frames after the gap go behind it.
Until 2026-12-06 it was put from the listener with ``DROP``, ahead of nothing: once in CI a
planner got every track after an outage and never the notice of the frames missed in it.

Zenoh reports a miss by publisher (its entity id), not by key: the subscriber callback
notes which key each publisher publishes on, so that a miss can be told to its sensor.
"""

from __future__ import annotations

import threading
from collections.abc import Callable

import zenoh
from zenoh import ext

from simpletrack.server.announcer import Announcer
from simpletrack.server.logs import get_logger
from simpletrack.server.metrics import Metrics
from simpletrack.server.outbox import missed_notice
from simpletrack.wire.codec import encode
from simpletrack.wire.keys import Keys

log = get_logger("service")

Source = tuple[str, int]  # (zenoh id, entity id) of a publisher


def source_of(sample: zenoh.Sample) -> Source | None:
    info = sample.source_info
    if info is None or info.source_id is None:
        return None  # a plain publisher: no sequence numbers, nothing to miss
    sid = info.source_id
    return str(sid.zid), int(sid.eid)


class MissCounter:
    """Wraps the intake callback to learn publishers' keys; ``on_miss`` counts, logs and
    announces frames that could not be recovered."""

    def __init__(
        self,
        intake: Callable[[zenoh.Sample], None],
        keys: Keys,
        metrics: Metrics,
        instance: str,
        announcer: Announcer,
    ) -> None:
        self._intake = intake
        self._keys = keys
        self._metrics = metrics
        self._instance = instance
        self._announcer = announcer
        self._keys_of: dict[Source, str] = {}
        self._lock = threading.Lock()
        self.by_sensor: dict[tuple[str, str], int] = {}

    def __call__(self, sample: zenoh.Sample) -> None:
        source = source_of(sample)
        if source is not None and source not in self._keys_of:
            # Written once per publisher; reads elsewhere tolerate a missing entry.
            self._keys_of[source] = str(sample.key_expr)
        self._intake(sample)

    def missed(self, vehicle: str, sensor: str) -> int:
        with self._lock:
            return self.by_sensor.get((vehicle, sensor), 0)

    def on_miss(self, miss: ext.Miss) -> None:
        source = (str(miss.source.zid), int(miss.source.eid))
        key = self._keys_of.get(source)
        sensor = self._keys.sensor_of(key) if key is not None else None
        if sensor is None:
            # Nothing received from this publisher yet: no sensor to charge it to.
            self._metrics.count_missed("", miss.nb)
            log.warning("frames_missed", source=f"{source[0]}/{source[1]}", missed=miss.nb)
            return
        self.announce(*sensor, miss.nb, "lost in transport and not in the publisher's cache")

    def announce(self, vehicle: str, name: str, n: int, why: str) -> None:
        """Count, log and announce ``n`` frames of a sensor that no member will track."""
        sensor = (vehicle, name)
        with self._lock:
            total = self.by_sensor[sensor] = self.by_sensor.get(sensor, 0) + n
        self._metrics.count_missed(vehicle, n)
        log.warning("frames_missed", vehicle=vehicle, sensor=name, missed=n, total=total)
        err = missed_notice(
            vehicle,
            name,
            f"{n} frames {why} ({total} on this sensor since the service started)",
            self._instance,
        )
        # Never waits: past the announcer's backlog the notice is counted and logged there.
        self._announcer.announce(self._keys.errors(vehicle, name), encode(err), sensor)


__all__ = ["MissCounter", "source_of"]
