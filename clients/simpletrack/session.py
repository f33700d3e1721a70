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
than fail at start.
"""

from __future__ import annotations

import argparse
import json
from enum import StrEnum
from pathlib import Path
from typing import Annotated

import zenoh
from pydantic import BaseModel, ConfigDict, Field, field_validator, model_validator

ZENOH_ENDPOINT_HELP = "e.g. tcp/127.0.0.1:7447 (see Zenoh endpoint syntax)"


class ZenohMode(StrEnum):
    PEER = "peer"  # embedded: talks to other peers directly, no router needed
    CLIENT = "client"  # talks only through the router(s) given with --connect


Endpoint = Annotated[str, Field(min_length=3, max_length=256)]


class ZenohOptions(BaseModel):
    """How to open a Zenoh session."""

    model_config = ConfigDict(frozen=True, extra="forbid")

    mode: ZenohMode = Field(
        default=ZenohMode.PEER, description="peer (embedded) or client of routers"
    )
    listen: list[Endpoint] = Field(
        default_factory=list,
        description="endpoints to listen on (peer mode only); never all interfaces by default",
    )
    connect: list[Endpoint] = Field(
        default_factory=list, description="endpoints (peers or routers) to connect to"
    )
    multicast_scouting: bool = Field(default=False, description="discover peers by UDP multicast")
    config_file: Path | None = Field(
        default=None,
        description="Zenoh JSON5 config file to start from (TLS, access control); options above override it where given",
    )
    connect_timeout_ms: int | None = Field(
        default=None,
        ge=-1,
        description="how long to try the connect endpoints at start (-1: wait for the router forever)",
    )

    @field_validator("listen", "connect")
    @classmethod
    def _endpoint_syntax(cls, v: list[str]) -> list[str]:
        for e in v:
            proto, sep, addr = e.partition("/")
            if not sep or not proto or not addr:
                raise ValueError(
                    f"endpoint {e!r} must look like PROTO/ADDRESS, {ZENOH_ENDPOINT_HELP}"
                )
        return v

    @field_validator("config_file")
    @classmethod
    def _file_exists(cls, v: Path | None) -> Path | None:
        if v is not None and not v.is_file():
            raise ValueError(f"zenoh config file {str(v)!r} does not exist")
        return v

    @model_validator(mode="after")
    def _client_needs_router(self) -> ZenohOptions:
        if self.config_file is not None:
            return self  # the file may name the routers
        if self.mode is ZenohMode.CLIENT and not self.connect and not self.multicast_scouting:
            raise ValueError("client mode needs at least one --connect endpoint (a router)")
        if self.mode is ZenohMode.CLIENT and self.listen:
            raise ValueError("client mode does not listen; drop --listen or use --mode peer")
        return self

    @classmethod
    def from_args(cls, args: argparse.Namespace) -> ZenohOptions:
        """Options from the flags added by ``add_zenoh_args`` (raises pydantic ValidationError)."""
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
            given = self.model_fields_set
            if "mode" in given:
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
        return config


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
        options = ZenohOptions.model_validate(kwargs)
    elif kwargs:
        options = ZenohOptions.model_validate({**options.model_dump(), **kwargs})
    return zenoh.open(options.to_config())


class Congestion(StrEnum):
    """What a publisher does when Zenoh cannot keep up: wait (lossless) or drop the sample."""

    BLOCK = "block"
    DROP = "drop"


# Where a service listens by default, and so where a client looks for one on this machine.
DEFAULT_LISTEN = ("tcp/127.0.0.1:7447",)
