"""Zenoh session options shared by every command that talks to Zenoh.

    parser = argparse.ArgumentParser()
    add_zenoh_args(parser)                      # --mode, --listen (repeatable), --connect (repeatable)
    options = ZenohOptions.from_args(args)      # or a ZenohOptions built by hand / from settings
    with open_session(options) as session: ...  # closes on every exit path

Multicast scouting is off and nothing listens unless asked: peers find each other only through
explicit ``--listen``/``--connect`` endpoints (e.g. ``tcp/127.0.0.1:7447``), so a process never
opens a port on every interface by accident. In client mode ``--connect`` names the router(s).

``--zenoh-config FILE`` starts from a Zenoh JSON5 config file instead (TLS/mTLS endpoints and
certificates, access control, timeouts: see deploy/zenoh/); the explicit options above are laid
over it only where given. ``connect_timeout_ms = -1`` makes a client wait for its router rather
than fail at start; ``open_session_waiting`` waits too, but gives up when its caller says stop.

A lost connection is retried every ``reconnect_max_ms`` at most: Zenoh's own back-off grows to
4 s, which cost 3.6 s of frames after a 3 s router outage. ``RouterWatch`` tells which routers
a session is connected to right now (readiness, metrics, delivery reports).
"""

from __future__ import annotations

import argparse
import errno
import json
import re
import threading
import time
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field, replace
from enum import StrEnum
from pathlib import Path
from typing import Any, cast

import zenoh

ZENOH_ENDPOINT_HELP = "e.g. tcp/127.0.0.1:7447 (see Zenoh endpoint syntax)"
ENDPOINT_LENGTH = (3, 256)
# Retrying every second at most loses at most ~1 s after a router returns; a refused TCP
# connect costs the router next to nothing, so a fleet retrying this often is affordable.
DEFAULT_RECONNECT_MAX_MS = 1000
RECONNECT_FIRST_MS = 100
# Zenoh closes a link when a BLOCK put has waited this long for room (its default is 5 s) and
# loses every sample queued on it, silently: a plain publisher's put just returns. A burst the
# service needs longer than that to drain (loopback socket buffers alone held ~15,000 small
# frames) lost 75% of its frames. The lease does not end a blocked put (a stopped service held
# one for minutes with no limit here): this wait is what a hung peer costs its BLOCK publishers.
BLOCK_WAIT_BEFORE_CLOSE_KEY = "transport/link/tx/queue/congestion_control/block/wait_before_close"
ZENOH_DEFAULT_WAIT_BEFORE_CLOSE_US = 5_000_000
BLOCK_WAIT_BEFORE_CLOSE_US = 60_000_000


class ZenohMode(StrEnum):
    PEER = "peer"  # embedded: talks to other peers directly, no router needed
    CLIENT = "client"  # talks only through the router(s) given with --connect


# The rules, shared with the settings form of these options (simpletrack.server.settings).


def check_endpoints(endpoints: Iterable[str]) -> None:
    for e in endpoints:
        proto, sep, addr = e.partition("/")
        if not sep or not proto or not addr:
            raise ValueError(f"endpoint {e!r} must look like PROTO/ADDRESS, {ZENOH_ENDPOINT_HELP}")


def check_config_file(path: Path | None) -> None:
    if path is not None and not path.is_file():
        raise ValueError(f"zenoh config file {str(path)!r} does not exist")


def check_roles(
    mode: ZenohMode,
    listen: list[str],
    connect: list[str],
    multicast_scouting: bool,
    config_file: Path | None,
) -> None:
    if config_file is not None:
        return  # the file may name the routers
    if mode is ZenohMode.CLIENT and not connect and not multicast_scouting:
        raise ValueError("client mode needs at least one --connect endpoint (a router)")
    if mode is ZenohMode.CLIENT and listen:
        raise ValueError("client mode does not listen; drop --listen or use --mode peer")


_UNSET: Any = object()  # "not given": over a config file only given options are laid


@dataclass(frozen=True, slots=True, init=False)
class ZenohOptions:
    """How to open a Zenoh session. Immutable; a bad value raises ValueError.

    Defaults: peer mode, listen and connect nowhere, no multicast scouting, no config file,
    Zenoh's own connect timeout. ``given`` names the options passed explicitly."""

    mode: ZenohMode
    listen: list[str]  # endpoints to listen on (peer mode only); never all interfaces
    connect: list[str]  # endpoints (peers or routers) to connect to
    multicast_scouting: bool
    config_file: Path | None  # Zenoh JSON5 config to start from (TLS, access control)
    connect_timeout_ms: int | None  # -1: a client waits for its router forever
    reconnect_max_ms: int  # longest wait between two attempts to (re)connect an endpoint
    given: frozenset[str] = field(init=False, compare=False, repr=False)

    def __init__(
        self,
        *,
        mode: ZenohMode | str = _UNSET,
        listen: Iterable[str] = _UNSET,
        connect: Iterable[str] = _UNSET,
        multicast_scouting: bool = _UNSET,
        config_file: Path | str | None = _UNSET,
        connect_timeout_ms: int | None = _UNSET,
        reconnect_max_ms: int = _UNSET,
    ) -> None:
        args = {
            "mode": mode,
            "listen": listen,
            "connect": connect,
            "multicast_scouting": multicast_scouting,
            "config_file": config_file,
            "connect_timeout_ms": connect_timeout_ms,
            "reconnect_max_ms": reconnect_max_ms,
        }
        given = frozenset(k for k, v in args.items() if v is not _UNSET)
        mode = ZenohMode.PEER if mode is _UNSET else _mode(mode)
        listen = [] if listen is _UNSET else _endpoints("listen", listen)
        connect = [] if connect is _UNSET else _endpoints("connect", connect)
        if multicast_scouting is _UNSET:
            multicast_scouting = False
        elif type(multicast_scouting) is not bool:
            raise ValueError("multicast_scouting: Input should be a valid boolean")
        path = None if config_file is _UNSET or config_file is None else Path(config_file)
        check_config_file(path)
        if connect_timeout_ms is _UNSET:
            connect_timeout_ms = None
        elif connect_timeout_ms is not None:
            if type(connect_timeout_ms) is not int:
                raise ValueError("connect_timeout_ms: Input should be a valid integer")
            if connect_timeout_ms < -1:
                raise ValueError("connect_timeout_ms: Input should be greater than or equal to -1")
        if reconnect_max_ms is _UNSET:
            reconnect_max_ms = DEFAULT_RECONNECT_MAX_MS
        elif type(reconnect_max_ms) is not int:
            raise ValueError("reconnect_max_ms: Input should be a valid integer")
        elif reconnect_max_ms < RECONNECT_FIRST_MS:
            raise ValueError(
                f"reconnect_max_ms: Input should be greater than or equal to {RECONNECT_FIRST_MS}"
            )
        check_roles(mode, listen, connect, multicast_scouting, path)
        for name, value in (
            ("mode", mode),
            ("listen", listen),
            ("connect", connect),
            ("multicast_scouting", multicast_scouting),
            ("config_file", path),
            ("connect_timeout_ms", connect_timeout_ms),
            ("reconnect_max_ms", reconnect_max_ms),
            ("given", given),
        ):
            object.__setattr__(self, name, value)

    @classmethod
    def from_args(cls, args: argparse.Namespace) -> ZenohOptions:
        """Options from the flags added by ``add_zenoh_args`` (raises ValueError)."""
        return cls(
            mode=args.zenoh_mode or ZenohMode.PEER,
            listen=list(args.zenoh_listen or []),
            connect=list(args.zenoh_connect or []),
            config_file=getattr(args, "zenoh_config", None),
        )

    def to_config(self) -> zenoh.Config:
        if self.config_file is not None:
            # The file is the base: only what was given explicitly is laid over it.
            config = zenoh.Config.from_file(str(self.config_file))
            if "mode" in self.given:
                config.insert_json5("mode", json.dumps(self.mode.value))
            if self.listen:
                config.insert_json5("listen/endpoints", json.dumps(list(self.listen)))
            if self.connect:
                config.insert_json5("connect/endpoints", json.dumps(list(self.connect)))
        else:
            config = zenoh.Config()
            config.insert_json5("mode", json.dumps(self.mode.value))
            config.insert_json5("listen/endpoints", json.dumps(list(self.listen)))
            config.insert_json5("connect/endpoints", json.dumps(list(self.connect)))
            config.insert_json5("scouting/multicast/enabled", json.dumps(self.multicast_scouting))
        if self.connect_timeout_ms is not None:
            config.insert_json5("connect/timeout_ms", json.dumps(self.connect_timeout_ms))
        if self.config_file is None or "reconnect_max_ms" in self.given:
            retry = {
                "period_init_ms": RECONNECT_FIRST_MS,
                "period_max_ms": self.reconnect_max_ms,
                "period_increase_factor": 2,
            }
            config.insert_json5("connect/retry", json.dumps(retry))
        if json.loads(config.get_json(BLOCK_WAIT_BEFORE_CLOSE_KEY)) == (
            ZENOH_DEFAULT_WAIT_BEFORE_CLOSE_US
        ):
            # Over a config file only Zenoh's default is replaced: a value set there is kept.
            config.insert_json5(BLOCK_WAIT_BEFORE_CLOSE_KEY, json.dumps(BLOCK_WAIT_BEFORE_CLOSE_US))
        return config

    def is_client(self) -> bool:
        """True when the session will be a client of routers (also when a config file says so)."""
        if "mode" in self.given or self.config_file is None:
            return self.mode is ZenohMode.CLIENT
        return bool(json.loads(self.to_config().get_json("mode")) == ZenohMode.CLIENT.value)


def _mode(value: ZenohMode | str) -> ZenohMode:
    try:
        return ZenohMode(value)
    except ValueError:
        raise ValueError("mode: Input should be 'peer' or 'client'") from None


def _endpoints(name: str, values: Iterable[str]) -> list[str]:
    if isinstance(values, str | bytes) or not isinstance(values, Iterable):
        raise ValueError(f"{name}: Input should be a valid list")
    out = list(values)
    lo, hi = ENDPOINT_LENGTH
    for i, e in enumerate(out):
        if not isinstance(e, str):
            raise ValueError(f"{name}.{i}: Input should be a valid string")
        if len(e) < lo:
            raise ValueError(f"{name}.{i}: String should have at least {lo} characters")
        if len(e) > hi:
            raise ValueError(f"{name}.{i}: String should have at most {hi} characters")
    check_endpoints(out)
    return out


def add_zenoh_args(parser: argparse.ArgumentParser) -> None:
    """Add ``--mode peer|client``, repeatable ``--listen`` and ``--connect``.

    Defaults are None/empty so that callers can layer them over a config file."""
    group = parser.add_argument_group("zenoh")
    group.add_argument(
        "--mode",
        dest="zenoh_mode",
        choices=[m.value for m in ZenohMode],
        default=None,
        help="peer: embedded, no router needed (default); client: through --connect routers",
    )
    group.add_argument(
        "--listen",
        dest="zenoh_listen",
        action="append",
        metavar="ENDPOINT",
        help=f"listen on this endpoint (repeatable), {ZENOH_ENDPOINT_HELP}",
    )
    group.add_argument(
        "--connect",
        dest="zenoh_connect",
        action="append",
        metavar="ENDPOINT",
        help=f"connect to this peer or router (repeatable), {ZENOH_ENDPOINT_HELP}",
    )
    group.add_argument(
        "--zenoh-config",
        dest="zenoh_config",
        type=Path,
        metavar="FILE",
        help="start from this Zenoh JSON5 config (TLS/mTLS, access control); flags override it",
    )


def zenoh_overrides(args: argparse.Namespace) -> dict[str, object]:
    """Only the zenoh flags the user actually gave, for layering over settings."""
    out: dict[str, object] = {}
    if getattr(args, "zenoh_mode", None):
        out["mode"] = args.zenoh_mode
    if getattr(args, "zenoh_listen", None):
        out["listen"] = list(args.zenoh_listen)
    if getattr(args, "zenoh_connect", None):
        out["connect"] = list(args.zenoh_connect)
    if getattr(args, "zenoh_config", None):
        out["config_file"] = args.zenoh_config
    return out


def open_session(options: ZenohOptions | None = None, **kwargs: object) -> zenoh.Session:
    """Open a session; use it as a context manager (or call ``close()``) on every exit path:
    a process holding an open session with callback subscribers can hang at exit.

    ``open_session(mode="peer", connect=["tcp/127.0.0.1:7447"])`` also works."""
    if options is None:
        options = ZenohOptions(**kwargs)  # type: ignore[arg-type]
    elif kwargs:
        # Every option then counts as given (as the pydantic model did).
        options = replace(options, **cast(dict[str, Any], kwargs))
    return zenoh.open(options.to_config())


# Zenoh's errors end each cause with the Rust source line that raised it:
# "... (os error 98) at /root/.cargo/git/checkouts/zenoh-.../io/zenoh-link-commons/src/tcp.rs:61."
_RUST_LOCATION = re.compile(r"\s+at \S+\.rs:\d+\.?")
_LISTENER = re.compile(r"create a new \w+ listener bound to (?P<endpoint>\S+?): \[")
_OS_ERROR = re.compile(r"\(os error (?P<code>\d+)\)")


def without_rust_locations(error: BaseException | str) -> str:
    """Zenoh's error message without the Rust source locations it carries."""
    return _RUST_LOCATION.sub("", str(error)).strip()


def listen_error(error: BaseException | str) -> str | None:
    """One line a user can act on when opening a session failed on a listen endpoint (in
    use, not an address of this machine, a privileged port); None for any other error."""
    text = str(error)
    listener, os_error = _LISTENER.search(text), _OS_ERROR.search(text)
    if listener is None or os_error is None:
        return None
    where, code = listener["endpoint"], int(os_error["code"])
    if code == errno.EADDRINUSE:
        why = "the address is in use (another simpletrack service or a Zenoh router?)"
        return f"cannot listen on {where}: {why}; pass --listen with a free port"
    if code == errno.EADDRNOTAVAIL:
        return (
            f"cannot listen on {where}: no network interface of this machine has that "
            "address; pass --listen with one of its addresses (e.g. tcp/127.0.0.1:7447)"
        )
    if code == errno.EACCES:
        return (
            f"cannot listen on {where}: permission denied (a port below 1024 needs "
            "privileges); pass --listen with a higher port"
        )
    return None


def open_session_waiting(
    options: ZenohOptions, stop: threading.Event, attempt_ms: int = 500
) -> zenoh.Session | None:
    """Open a session, trying again until it opens or ``stop`` is set (then None).

    A client whose routers are all down fails at once; this keeps trying, ``attempt_ms`` per
    try, so that a process started before its router comes up with it. The calling thread
    runs Python between tries: signal handlers (SIGTERM) still run."""
    while not stop.is_set():
        config = options.to_config()
        config.insert_json5("connect/timeout_ms", json.dumps(attempt_ms))
        try:
            return zenoh.open(config)
        except zenoh.ZError:
            # A refused connect fails at once: pace the tries like a timed-out one.
            stop.wait(attempt_ms / 1000)
    return None


class RouterWatch:
    """The routers a session is connected to now, kept from Zenoh's transport events (a
    router killed is gone within milliseconds; a hung one after the lease, 10 s by default).

    ``on_change(connected, router_zid)`` runs on a Zenoh thread: keep it short."""

    def __init__(
        self,
        session: zenoh.Session,
        on_change: Callable[[bool, str], None] | None = None,
    ) -> None:
        self._lock = threading.Lock()
        self._routers: set[str] = set()
        self._on_change = on_change
        self.changed_at = time.monotonic()
        self._listener = session.info.declare_transport_events_listener(
            self._on_event, history=True
        )

    def _on_event(self, event: zenoh.TransportEvent) -> None:
        transport = event.transport
        if transport.whatami != zenoh.WhatAmI.ROUTER:
            return
        zid = str(transport.zid)
        up = event.kind == zenoh.SampleKind.PUT
        with self._lock:
            before = len(self._routers)
            (self._routers.add if up else self._routers.discard)(zid)
            if before != len(self._routers):
                self.changed_at = time.monotonic()
        if self._on_change is not None:
            self._on_change(up, zid)

    @property
    def routers(self) -> int:
        with self._lock:
            return len(self._routers)

    def undeclare(self) -> None:
        self._listener.undeclare()  # type: ignore[no-untyped-call]


class Congestion(StrEnum):
    """What a publisher does when Zenoh cannot keep up: wait (lossless) or drop the sample."""

    BLOCK = "block"
    DROP = "drop"


# Where a service listens by default, and so where a client looks for one on this machine.
DEFAULT_LISTEN = ("tcp/127.0.0.1:7447",)
