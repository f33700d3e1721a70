"""What the client commands share: Zenoh flags with a local-service default, the key prefix,
and turning connection failures into one-line errors."""

from __future__ import annotations

import argparse
import re
from dataclasses import replace

import zenoh

from simpletrack.cli.errors import UserError
from simpletrack.session import (
    DEFAULT_LISTEN,
    ZenohOptions,
    add_zenoh_args,
    listen_error,
    open_session,
    without_rust_locations,
)

ZENOH_NOTE = (
    "Zenoh: peer mode by default, connecting to a service on this machine\n"
    f"({DEFAULT_LISTEN[0]}); use --connect to reach another one, --mode client for routers."
)

_PREFIX = re.compile(
    r"^[A-Za-z0-9_][A-Za-z0-9_.\-]{0,63}(/[A-Za-z0-9_][A-Za-z0-9_.\-]{0,63}){0,7}$"
)


def add_client_args(parser: argparse.ArgumentParser, prefix: bool = True) -> None:
    add_zenoh_args(parser)
    if prefix:
        parser.add_argument(
            "--prefix", default="fleet", help="first key chunk(s) of the service (default fleet)"
        )


def check_prefix(prefix: str) -> str:
    if not _PREFIX.fullmatch(prefix):  # match's '$' would let a trailing newline through
        raise UserError(
            f"--prefix {prefix!r} must be key chunks of letters, digits, _ . - (no wildcards)"
        )
    return prefix


def client_options(args: argparse.Namespace) -> ZenohOptions:
    """The session options of a client command. A peer given no endpoints connects to the
    service's default listen endpoint on this machine."""
    try:
        options = ZenohOptions.from_args(args)
        if options.mode.value == "peer" and not options.listen and not options.connect:
            options = replace(options, connect=list(DEFAULT_LISTEN))
        return options
    except ValueError as exc:
        raise UserError(str(exc)) from None


def open_client_session(options: ZenohOptions) -> zenoh.Session:
    try:
        return open_session(options)
    except zenoh.ZError as exc:
        where = ", ".join(options.connect) or "no endpoint"
        raise UserError(
            listen_error(exc)
            or f"cannot open a Zenoh session ({options.mode.value}, {where}): "
            f"{without_rust_locations(exc)}"
        ) from None
