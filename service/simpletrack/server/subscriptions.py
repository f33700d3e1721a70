"""Per-sensor subscriptions (``subscribe = "owned"``): a member subscribes only to the
sensors it owns or stands by for, found from the vehicles' own liveliness tokens, so that
its inbound traffic is its share of the fleet instead of all of it.

A ``DetectionPublisher`` (an advanced publisher with publisher detection) holds the token
``<detections key>/@adv/pub/<zid>/<eid>/...`` while it lives; a liveliness subscriber on
``<prefix>/*/*/detections/@adv/pub/**`` therefore lists the sensors being published. A
publisher without that token (a plain ``put``) is never heard in this mode: use the default
``subscribe = "wide"`` for such fleets (docs/SCALE.md).

Declarations happen on this module's own thread, never in a Zenoh callback.
"""

from __future__ import annotations

import threading
from collections.abc import Callable
from typing import Any

import zenoh
from zenoh import ext

from simpletrack.server.group import Membership, Role, undeclare
from simpletrack.server.logs import get_logger
from simpletrack.wire.keys import DETECTIONS, Keys

log = get_logger("group")
ADV_TOKENS = "@adv/pub/**"


class Subscriptions:
    def __init__(
        self,
        session: zenoh.Session,
        keys: Keys,
        membership: Membership,
        handler: Callable[[], Any],
        on_miss: Callable[[ext.Miss], None],
        history_frames: int,
        stream_of: Callable[[str, str], str] = lambda v, s: f"{v}/{s}",
    ) -> None:
        self.session, self.keys, self.membership = session, keys, membership
        self._handler, self._on_miss, self._history = handler, on_miss, history_frames
        self._stream_of = stream_of  # a fused sensor's role is its vehicle's
        self._tokens: dict[str, set[str]] = {}  # vehicle/sensor -> its publishers' tokens
        self._subs: dict[str, tuple[Any, Any]] = {}  # vehicle/sensor -> (listener, sub)
        self._lock = threading.Lock()
        self._wake = threading.Event()
        self._stop = threading.Event()
        self._idle = threading.Event()
        self._thread = threading.Thread(target=self._run, name="subscriptions", daemon=True)
        self._token_sub: Any = None

    @property
    def subscribed(self) -> int:
        return len(self._subs)

    def start(self) -> None:
        self._token_sub = self.session.liveliness().declare_subscriber(
            f"{self.keys.prefix}/*/*/{DETECTIONS}/{ADV_TOKENS}", self._on_token, history=True
        )
        self._thread.start()

    def changed(self) -> None:
        """The membership changed: roles, hence the wanted sensors, may have."""
        self._idle.clear()
        self._wake.set()

    def settle(self, timeout: float) -> bool:
        """Wait until the subscriptions match the roles (at start, before the token)."""
        self.changed()
        return self._idle.wait(timeout)

    def _on_token(self, sample: zenoh.Sample) -> None:
        key = str(sample.key_expr)
        names = self.keys.sensor_of(key.split(f"/{DETECTIONS}/", 1)[0] + f"/{DETECTIONS}")
        if names is None:
            return
        sensor = f"{names[0]}/{names[1]}"
        with self._lock:
            tokens = self._tokens.setdefault(sensor, set())
            if sample.kind == zenoh.SampleKind.PUT:
                tokens.add(key)
            else:
                tokens.discard(key)
                if not tokens:
                    del self._tokens[sensor]
        self.changed()

    def _wanted(self) -> set[str]:
        with self._lock:
            published = list(self._tokens)
        return {
            s
            for s in published
            if self.membership.role(self._stream_of(*s.split("/"))) is not Role.NONE
        }

    def _run(self) -> None:
        while not self._stop.is_set():
            self._wake.wait(0.5)
            self._wake.clear()
            if self._stop.is_set():
                break
            try:
                self._reconcile()
            except zenoh.ZError as e:
                log.warning("subscriptions_failed", error=str(e))
            if not self._wake.is_set():
                self._idle.set()

    def _reconcile(self) -> None:
        wanted = self._wanted()
        for sensor in [s for s in self._subs if s not in wanted]:
            undeclare(*self._subs.pop(sensor))
        for sensor in sorted(wanted - set(self._subs)):
            vehicle, name = sensor.split("/")
            sub = ext.declare_advanced_subscriber(
                self.session,
                self.keys.detections(vehicle, name),
                self._handler(),
                history=ext.HistoryConfig(detect_late_publishers=True, max_samples=self._history),
                recovery=ext.RecoveryConfig(heartbeat=True, periodic_queries=None),
            )
            self._subs[sensor] = (sub.sample_miss_listener(self._on_miss), sub)

    def close(self) -> None:
        """Stop and undeclare everything (first thing at shutdown: no new frames)."""
        self._stop.set()
        self._wake.set()
        if self._thread.is_alive():
            self._thread.join(5)
        if self._token_sub is not None:
            undeclare(self._token_sub)
            self._token_sub = None
        for pair in self._subs.values():
            undeclare(*pair)
        self._subs.clear()


__all__ = ["Subscriptions"]
