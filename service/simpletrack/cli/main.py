"""The ``simpletrack`` command: one entry point, one module per subcommand.

Each command module exposes ``register(subparsers)`` which adds its parser and sets
``func(args) -> int`` as the default; ``build_parser`` imports and registers every one.
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence
from importlib.metadata import PackageNotFoundError, version

from simpletrack.cli.errors import UserError

# What a light install (the client library only) lacks for the commands.
EXTRAS_HINT = (
    "the simpletrack command needs the service extra: pip install 'simpletrack-service[service]'"
)
DISTRIBUTION = "simpletrack-service"


def distribution_version() -> str:
    """The installed distribution's version: what a bug report needs (a source tree run
    without installing has none)."""
    try:
        return version(DISTRIBUTION)
    except PackageNotFoundError:
        return "unknown (not installed)"


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="simpletrack",
        description="SimpleTrack 3D multi-object tracking as a Zenoh streaming service.",
    )
    parser.add_argument(
        "--version", action="version", version=f"simpletrack {distribution_version()}"
    )
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", required=True)
    from simpletrack.cli import (
        bench,
        bridge,
        demo,
        eval,
        plot,
        record,
        replay,
        serve,
        status,
        track,
        view,
        watch,
    )

    for command in (
        track,
        eval,
        plot,
        replay,
        record,
        demo,
        watch,
        status,
        bench,
        serve,
        bridge,
        view,
    ):
        command.register(sub)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    try:
        parser = build_parser()
    except ModuleNotFoundError as exc:
        print(f"simpletrack: {EXTRAS_HINT} (missing module {exc.name!r})", file=sys.stderr)
        return 2
    args = parser.parse_args(argv)
    try:
        return int(args.func(args))
    except UserError as exc:
        print(f"simpletrack {args.command}: error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        return 130
    except BrokenPipeError:  # output piped into head & co.: not an error of ours
        sys.stderr.close()
        return 0


if __name__ == "__main__":
    sys.exit(main())
