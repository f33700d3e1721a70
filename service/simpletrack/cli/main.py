"""The ``simpletrack`` command: one entry point, one module per subcommand.

Each command module exposes ``register(subparsers)`` which adds its parser and sets
``func(args) -> int`` as the default. ``main`` imports only the module of the command it runs
(the others appear in ``--help`` by their line in ``COMMANDS``), so the client-side commands
run on the light install, and a command whose dependencies are missing names its extra.
"""

from __future__ import annotations

import argparse
import importlib
import sys
from collections.abc import Sequence
from importlib.metadata import PackageNotFoundError, version

from simpletrack.cli.errors import USAGE_EXIT, UserError

DISTRIBUTION = "simpletrack-service"

# Command -> its one line in ``simpletrack --help``; the module is simpletrack.cli.<command>.
COMMANDS: dict[str, str] = {
    "track": "track detection files offline (nuScenes)",
    "eval": "evaluate tracking results (KITTI 3D MOT)",
    "plot": "bird's-eye-view PNGs, trajectory overviews and animations of recorded tracks",
    "replay": "publish KITTI, nuScenes or MCAP-recorded detections onto Zenoh at their rate",
    "record": "record published tracks to files (KITTI results or JSON lines), or messages to MCAP",
    "demo": "the service and a simulated fleet with a live view (no router, no data files)",
    "watch": "live terminal table of the tracks a planner receives",
    "status": "members of the group on a prefix and the sensors each owns",
    "bench": "benchmarks: the tracker core's cost curve, the service's latency and capacity",
    "serve": "run the tracking service over Zenoh",
    "bridge": "adapters between the service and other middlewares (ros2)",
    "view": "live bird's-eye view of the tracks in the browser",
}

# A missing top-level module -> the extra that brings it (pyproject.toml).
EXTRA_OF: dict[str, str] = {
    "scipy": "service",
    "numba": "service",
    "llvmlite": "service",
    "pydantic": "service",
    "pydantic_settings": "service",
    "prometheus_client": "service",
    "rich": "service",
    "yaml": "service",
    "mcap": "mcap",
    "zstandard": "mcap",
    "matplotlib": "plot",
    "PIL": "plot",
    "foxglove": "foxglove",
}


def distribution_version() -> str:
    """The installed distribution's version: what a bug report needs (a source tree run
    without installing has none)."""
    try:
        return version(DISTRIBUTION)
    except PackageNotFoundError:
        return "unknown (not installed)"


def extra_hint(missing: str | None) -> str | None:
    """``needs the X extra: pip install ...`` for a module an extra brings, else None."""
    extra = EXTRA_OF.get((missing or "").split(".")[0])
    if extra is None:
        return None
    return f"needs the {extra} extra: pip install '{DISTRIBUTION}[{extra}]' (missing module {missing!r})"


def build_parser(only: str | None = None) -> argparse.ArgumentParser:
    """Every command's parser, or with ``only`` that command's (the others by name and help
    line alone, so nothing else is imported)."""
    parser = argparse.ArgumentParser(
        prog="simpletrack",
        description="SimpleTrack 3D multi-object tracking as a Zenoh streaming service.",
    )
    parser.add_argument(
        "--version", action="version", version=f"simpletrack {distribution_version()}"
    )
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", required=True)
    for name, line in COMMANDS.items():
        if only is None or name == only:
            importlib.import_module(f"simpletrack.cli.{name}").register(sub)
        else:
            sub.add_parser(name, help=line)
    return parser


def _command(argv: Sequence[str]) -> str | None:
    first = next((a for a in argv if not a.startswith("-")), None)
    return first if first in COMMANDS else None


def main(argv: Sequence[str] | None = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    command = _command(argv)
    try:
        # Without a known command (--help, --version, a typo) no command module is imported.
        args = build_parser(only=command or "").parse_args(argv)
        return int(args.func(args))
    except UserError as exc:
        print(f"simpletrack {command}: error: {exc}", file=sys.stderr)
        return USAGE_EXIT
    except ModuleNotFoundError as exc:  # the command's, or an option's imported when used
        hint = extra_hint(exc.name)
        if hint is None:
            raise
        print(f"simpletrack {command}: {hint}", file=sys.stderr)
        return USAGE_EXIT
    except KeyboardInterrupt:
        return 130
    except BrokenPipeError:  # output piped into head & co.: not an error of ours
        sys.stderr.close()
        return 0


if __name__ == "__main__":
    sys.exit(main())
