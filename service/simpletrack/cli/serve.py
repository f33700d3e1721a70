"""``simpletrack serve``: run the tracking service until SIGTERM/SIGINT."""

from __future__ import annotations

import argparse
import os
import sys
from enum import StrEnum
from pathlib import Path
from typing import Any

import zenoh

from simpletrack.cli.errors import UserError
from simpletrack.core.config import (
    PRESETS,
    MotionModel,
    OutputPolicy,
    TieOrder,
    VerticalOverlap,
)
from simpletrack.server import logs
from simpletrack.server.settings import (
    Backpressure,
    LogFormat,
    LogLevel,
    ServiceSettings,
    check_environment,
    load_settings,
)
from simpletrack.session import (
    add_zenoh_args,
    listen_error,
    without_rust_locations,
    zenoh_overrides,
)

EPILOG = """\
Settings come from defaults, then --config FILE (TOML or YAML), then SIMPLETRACK_* environment
variables (nested with __, e.g. SIMPLETRACK_ZENOH__MODE=client), then these flags. Every
setting is listed in docs/SERVICE.md. A SIMPLETRACK_* variable that is no setting (a typo)
stops the start; SIMPLETRACK_JIT, SIMPLETRACK_DATA and the native clients' build variables
are allowed.

key expressions (prefix "fleet" by default):
  in   <prefix>/<vehicle>/<sensor>/detections   DetectionFrame (msgpack, schemas/README.md)
  out  <prefix>/<vehicle>/<sensor>/tracks       TrackFrame
  out  <prefix>/<vehicle>/<sensor>/errors       FrameError (reason, offending seq)
       <prefix>/@simpletrack/<instance>/status  queryable: ServiceStatus

examples:
  # embedded peer on loopback, metrics on :9464, snapshots in ./state
  simpletrack serve --listen tcp/127.0.0.1:7447 --state-dir ./state
  # client of two routers, settings file, nuScenes classes
  simpletrack serve --mode client --connect tcp/10.0.0.1:7447 --connect tcp/10.0.0.2:7447 \\
      --config /etc/simpletrack.toml --preset nuscenes
  curl -s localhost:9464/metrics | grep simpletrack_frames
  # 4 member processes on one host (one core each): instances <id>-0..3, metrics ports
  # 9464..9467, listen ports 7447..7450, state in ./state/0..3
  simpletrack serve --processes 4 --listen tcp/127.0.0.1:7447 --state-dir ./state
  # as many members as this host's or container's CPUs hold: 8 CPUs / 2 workers = 4
  simpletrack serve --processes auto --workers 2 --listen tcp/127.0.0.1:7447

--processes N starts N child `simpletrack serve` processes and supervises them: child i gets
instance <instance>-<i>, metrics port <port>+i (0 stays 0) and state dir <state_dir>/<i>; in
peer mode it listens on each --listen endpoint's port + i and connects to its siblings, so a
vehicle connected to one child reaches them all; in client mode all connect to the same
routers. SIGTERM/SIGINT go to every child (exit code: the worst child's); a child that dies is
restarted after a back-off, and one that dies 6 times within a minute stops the group.

--processes auto: N = usable CPUs // workers (the setting, from flag, environment or file),
at least 1, at most 64. The usable CPUs are the affinity mask's (taskset, cpuset) capped by
the cgroup CPU quota rounded up (a container's `cpus:`, a pod's `limits.cpu`); the event
processes_auto logs the figure and how it was reached. An N of 1 runs in this process, as
--processes 1 does.
"""


def register(subparsers: Any) -> None:
    p: argparse.ArgumentParser = subparsers.add_parser(
        "serve",
        help="run the tracking service over Zenoh",
        description="Consume detection frames over Zenoh, track every sensor, publish tracks.",
        formatter_class=argparse.RawDescriptionHelpFormatter,
        epilog=EPILOG,
    )
    p.add_argument("--config", type=Path, metavar="FILE", help="TOML or YAML settings file")
    add_zenoh_args(p)
    p.add_argument("--metrics-port", type=int, metavar="PORT", help="HTTP port (0: off)")
    p.add_argument("--state-dir", type=Path, metavar="DIR", help="snapshot directory")
    p.add_argument("--prefix", metavar="PREFIX", help="first key chunk(s) (default fleet)")
    p.add_argument("--instance", metavar="ID", help="instance id (default from hostname)")
    p.add_argument("--preset", choices=list(PRESETS), help="tracker preset")
    p.add_argument("--class-overrides", type=Path, metavar="FILE", help="per-class overrides")
    tracker = p.add_argument_group("tracker options over the preset's (tracker.* settings)")
    tracker.add_argument("--motion", choices=_values(MotionModel), help="motion model")
    tracker.add_argument("--output", choices=_values(OutputPolicy), help="output policy")
    tracker.add_argument("--vertical-overlap", choices=_values(VerticalOverlap))
    tracker.add_argument("--tie-order", choices=_values(TieOrder), help="NMS tie order")
    tracker.add_argument(
        "--coast-score-decay", type=float, metavar="X", help="coasting score factor per frame"
    )
    p.add_argument("--workers", type=int, metavar="N", help="tracker threads")
    p.add_argument("--backpressure", choices=_values(Backpressure), help="what a full queue does")
    p.add_argument("--log-level", choices=_values(LogLevel))
    p.add_argument("--log-format", choices=_values(LogFormat))
    p.add_argument(
        "--processes",
        metavar="N",
        help="run N member processes under a supervisor (default 1: this process; auto: "
        "usable CPUs / workers; see below)",
    )
    p.set_defaults(func=run, serve_parser=p)


def _values(enum: type[StrEnum]) -> list[str]:
    return [m.value for m in enum]


_FLAGS = (
    "metrics_port",
    "state_dir",
    "prefix",
    "instance",
    "preset",
    "class_overrides",
    "workers",
    "backpressure",
    "log_level",
    "log_format",
)
_TRACKER_FLAGS = ("motion", "output", "vertical_overlap", "tie_order", "coast_score_decay")


def settings_from_args(args: argparse.Namespace) -> ServiceSettings:
    """The settings the flags, the ``--config`` file and the environment give (a
    ``SIMPLETRACK_*`` variable that is no setting is refused, not ignored)."""
    overrides: dict[str, Any] = {
        k: getattr(args, k) for k in _FLAGS if getattr(args, k) is not None
    }
    if z := zenoh_overrides(args):
        overrides["zenoh"] = z
    if t := {k: getattr(args, k) for k in _TRACKER_FLAGS if getattr(args, k) is not None}:
        overrides["tracker"] = t
    if args.config is not None and not args.config.is_file():
        raise UserError(f"--config {args.config}: no such file")
    try:
        check_environment(os.environ)
        return load_settings(args.config, overrides)
    except ValueError as e:
        raise UserError(str(e)) from None


def run(args: argparse.Namespace) -> int:
    from simpletrack.cli import processes

    # Parsed before the settings, so a bad N is refused first; auto needs their workers.
    wanted = processes.parse_processes(args.processes) if args.processes is not None else 1
    settings = settings_from_args(args)
    logs.configure(settings.log_format, settings.log_level)
    n = processes.resolve(wanted, settings.workers)
    if n > 1:
        return processes.supervise(args.serve_parser, args, settings, n)
    zenoh.init_log_from_env_or("error")
    # The tracker's many short numpy calls hold the GIL between them; at Python's default 5 ms
    # switch interval Zenoh's delivery threads wait behind a busy worker (measured: 10-sensor
    # p99 77 ms at 5 ms, 8 ms at 0.5 ms).
    sys.setswitchinterval(settings.gil_switch_interval_ms / 1000.0)

    from simpletrack.server import app  # heavy imports only once the arguments are known to be good

    try:
        return app.run(settings)
    except OSError as e:  # metrics port taken, state dir not writable
        raise UserError(
            f"{e.strerror or e}: {getattr(e, 'filename', '') or ''}".rstrip(": ")
        ) from None
    except zenoh.ZError as e:  # a listen port taken (another service?), a router unreachable
        raise UserError(
            listen_error(e) or f"cannot open the Zenoh session: {without_rust_locations(e)}"
        ) from None
    except app.StartError as e:
        raise UserError(str(e)) from None
