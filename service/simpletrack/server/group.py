"""The instances on one prefix as a group: who is alive, and which of them owns each sensor.

Membership is Zenoh's own: every instance holds the liveliness token
``<prefix>/@simpletrack/<instance>`` and keeps the live set from a liveliness subscriber (a
killed process's token is gone in milliseconds). Ownership is rendezvous hashing: each sensor
ranks the members by a hash of (member, sensor); the first owns it, the second stands by
for it (keeps its checkpoints and its recent frames). A member leaving moves only its own
sensors, a member joining only those it now ranks first for; no coordination is needed
beyond the views agreeing, which the token stream makes them do within milliseconds.

A client that loses its router sees every other token go at once: that is its outage, not
theirs, so departures seen while no router is connected (or within ``ROUTER_SETTLE_S`` of
its return) wait until the router has been back that long and are dropped if the member
reappeared (docs/SCALE.md, "What partitions do").
"""

from __future__ import annotations

import hashlib
import threading
import time
from collections.abc import Callable, Iterable
from typing import Any, TypeVar

import zenoh

from simpletrack.server.custody_machine import Role
from simpletrack.server.logs import get_logger
from simpletrack.wire.keys import SERVICE_CHUNK, Keys

log = get_logger("group")
T = TypeVar("T")
ROUTER_SETTLE_S = 2.0
TICK_S = 0.1


def weight(member: str, sensor: str) -> int:
    # blake2b, not hash(): every process, on every machine, must rank alike.
    digest = hashlib.blake2b(f"{member}\x00{sensor}".encode(), digest_size=8).digest()
    return int.from_bytes(digest, "big")


def ranking(members: Iterable[str], sensor: str) -> list[str]:
    """The members in the sensor's order of preference (ties, impossible in practice, by
    name so that every view agrees)."""
    return sorted(members, key=lambda m: (-weight(m, sensor), m))


class Membership:
    """The live members (this instance included) and each sensor's role here.

    ``role`` is called for every frame on the Zenoh callback: answered from a cache that a
    membership change replaces whole."""

    def __init__(
        self,
        me: str,
        keys: Keys,
        enabled: bool = True,
        routers: Callable[[], int] | None = None,
        on_change: Callable[[frozenset[str], frozenset[str]], None] | None = None,
    ) -> None:
        self.me, self.keys, self.enabled = me, keys, enabled
        self._routers = routers  # None: peer mode, a token gone is a member gone
        self._on_change = on_change
        self._lock = threading.Lock()
        self._members: frozenset[str] = frozenset({me})
        self._roles: dict[str, Role] = {}
        # Each sensor's ranking in the current view: the checkpoints and the release of
        # unowned streams ask it for every held sensor, twice a second.
        self._orders: dict[str, tuple[str, ...]] = {}
        self._leaving: dict[str, float] = {}  # member -> when its token went (client mode)
        self._router_back_at: float | None = None
        self._sub: zenoh.Subscriber[None] | None = None
        self._stop = threading.Event()
        self.declared = False  # this instance's own token is out (set by the service)
        self.twin = False
        # Vehicle fusion (server/streams.py): this instance fuses, and which members hold
        # the fusion token. A member counts as able from its token's first sight until it
        # leaves the view (its departure, not a router blip, is what ends it).
        self.fuses = False
        self._capable: set[str] = set()
        self._cap_sub: zenoh.Subscriber[None] | None = None
        self.on_gate: Callable[[bool], None] | None = None
        self._gate = False

    # ------------------------------------------------------------------ views
    @property
    def members(self) -> frozenset[str]:
        return self._members

    def role(self, sensor: str) -> Role:
        """This instance's role for ``vehicle/sensor`` in the current view."""
        if not self.enabled:
            return Role.OWNER
        roles = self._roles
        role = roles.get(sensor)
        if role is None:
            order = self._order(sensor)
            if order[0] == self.me:
                role = Role.OWNER
            elif len(order) > 1 and order[1] == self.me:
                role = Role.STANDBY
            else:
                role = Role.NONE
            if len(roles) < 1_000_000:  # bounded: a flood of made-up keys cannot grow it
                roles[sensor] = role
        return role

    def fusion_gate(self) -> bool:
        """Whether vehicles are fused now: this instance fuses and so does every member it
        sees (a member of before fusion holds no fusion token)."""
        if not self.fuses:
            return False
        if not self.enabled:
            return True
        return all(m == self.me or m in self._capable for m in self._members)

    def owner(self, sensor: str) -> str:
        return self._order(sensor)[0] if self.enabled else self.me

    def standby(self, sensor: str) -> str | None:
        """The member that would take ``sensor`` over if its owner went (None: alone)."""
        order = self._order(sensor)
        return order[1] if self.enabled and len(order) > 1 else None

    def _order(self, sensor: str) -> tuple[str, ...]:
        orders, members = self._orders, self._members
        order = orders.get(sensor)
        if order is None:
            order = tuple(ranking(members, sensor))
            if len(orders) < 1_000_000:  # bounded as the roles are
                orders[sensor] = order
        return order

    # ------------------------------------------------------------------ the token stream
    def start(self, session: zenoh.Session) -> None:
        if not self.enabled:
            return
        self._sub = session.liveliness().declare_subscriber(
            self.keys.liveliness("*"), self._on_token, history=True
        )
        if self.fuses:
            self._cap_sub = session.liveliness().declare_subscriber(
                self.keys.fusion_token("*"), self._on_capability, history=True
            )
        if self._routers is not None:
            threading.Thread(target=self._tick, name="group", daemon=True).start()

    def _member_of(self, key: str) -> str | None:
        parts = key.split("/")
        if len(parts) < 2 or parts[-2] != SERVICE_CHUNK:
            return None
        return parts[-1]

    def _on_token(self, sample: zenoh.Sample) -> None:
        member = self._member_of(str(sample.key_expr))
        if member is not None:
            self.token(member, sample.kind == zenoh.SampleKind.PUT)

    def _on_capability(self, sample: zenoh.Sample) -> None:
        parts = str(sample.key_expr).split("/")
        if len(parts) >= 3 and sample.kind == zenoh.SampleKind.PUT:
            self.can_fuse(parts[-2])

    def can_fuse(self, member: str) -> None:
        """A member's fusion token appeared: it stays able until it leaves the view."""
        with self._lock:
            self._capable.add(member)
        self._gate_changed()

    def _gate_changed(self) -> None:
        gate = self.fusion_gate()
        if gate != self._gate:
            self._gate = gate
            log.info("fusion_gate", fusing=gate, members=",".join(sorted(self._members)))
            if self.on_gate is not None:
                self.on_gate(gate)

    def token(self, member: str, up: bool) -> None:
        """A member's token appeared (``up``) or went."""
        if member == self.me:
            if up and not self.declared:
                self.twin = True  # another process already runs under this name
            return
        if up:
            with self._lock:
                self._leaving.pop(member, None)
            self._set(self._members | {member})
        elif self._routers is None:
            self._set(self._members - {member})
        else:
            with self._lock:
                self._leaving.setdefault(member, time.monotonic())

    def router_changed(self, connected: bool) -> None:
        """From the session's router watch: a router back starts the settle time."""
        with self._lock:
            self._router_back_at = time.monotonic() if connected else None

    def _tick(self) -> None:
        while not self._stop.wait(TICK_S):
            with self._lock:
                if not self._leaving or self._routers is None or self._routers() == 0:
                    continue
                back = self._router_back_at
                if back is not None and time.monotonic() - back < ROUTER_SETTLE_S:
                    continue
                gone = set(self._leaving)
                self._leaving.clear()
            self._set(self._members - gone)

    def _set(self, members: frozenset[str]) -> None:
        with self._lock:
            before = self._members
            if members == before:
                return
            self._members = members
            self._roles = {}
            self._orders = {}
            self._capable -= before - members  # gone: able again only with a new token
        log.info(
            "group_changed",
            members=",".join(sorted(members)),
            joined=",".join(sorted(members - before)) or None,
            left=",".join(sorted(before - members)) or None,
        )
        if self._on_change is not None:
            self._on_change(before, members)
        self._gate_changed()

    def close(self) -> None:
        self._stop.set()
        for sub in (self._sub, self._cap_sub):
            if sub is not None:
                undeclare(sub)
        self._sub = self._cap_sub = None


def on_zenoh(fn: Callable[[T], None]) -> zenoh.handlers.Callback[T]:
    """A handler that runs ``fn`` on Zenoh's own thread, for callbacks that never block. A
    plain callable gets a Python thread of its own per subscriber or miss listener: with one
    of each per stream held, two threads per stream, and a thread switch per message."""
    return zenoh.handlers.Callback(fn, indirect=False)


def undeclare(*entities: Any) -> None:
    """Undeclare Zenoh entities in order, logging (never raising) what fails: the session
    may be closing, or a receiver still borrowing one."""
    for entity in entities:
        try:
            entity.undeclare()
        except (zenoh.ZError, RuntimeError) as e:
            log.warning("undeclare_failed", error=str(e))


__all__ = ["Membership", "Role", "on_zenoh", "ranking", "undeclare", "weight"]
