"""The ``simpletrack`` command: one entry point, one module per subcommand.

Each command module exposes ``register(subparsers)`` which adds its parser and sets
``func(args) -> int`` as the default. Modules are imported only when listed here.
"""

from __future__ import annotations

import argparse
import importlib
import sys
from collections.abc import Sequence

COMMAND_MODULES: tuple[str, ...] = (
    # one module per subcommand
    "clients.commands.track",
    "clients.commands.eval",
    "clients.commands.plot",
    "clients.commands.replay",
    "clients.commands.record",
    "clients.commands.demo",
    "clients.commands.watch",
    "clients.commands.bench",
    "service.commands.serve",
)


class UserError(Exception):
    """A mistake in the command's arguments or inputs: printed as one line, exit code 2."""


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="simpletrack",
        description="SimpleTrack 3D multi-object tracking as a Zenoh streaming service.",
    )
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", required=True)
    for name in COMMAND_MODULES:
        importlib.import_module(name).register(sub)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    parser = build_parser()
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
    # Through the installed module, so `python -m service.cli` shares one UserError class.
    from service.cli import main as installed_main

    sys.exit(installed_main())
