"""``simpletrack status``: the instances on a prefix, what each holds and stands by for, and
the hand-offs and failovers each has seen (their status queryables, asked once)."""

from __future__ import annotations

import argparse
import dataclasses
import json
import sys
import time
from datetime import UTC, datetime

import zenoh

from simpletrack.cli.common import (
    ZENOH_NOTE,
    add_client_args,
    check_prefix,
    client_options,
    open_client_session,
)
from simpletrack.cli.errors import UserError
from simpletrack.wire import Rejection, SensorStatus, ServiceStatus, decode_message
from simpletrack.wire.keys import Keys
from simpletrack.wire.messages import VehicleStatus
from simpletrack.wire.reasons import SensorCondition

EPILOG = f"""\
One block per instance that answered: its view of the group's members, ready or not, queue
depth, sensors owned, sensors it stands by for, hand-offs in/out, failovers. Members that some instance sees but that did not answer are listed as silent.
With --sensors, one line per sensor owned: last seq and its stamp (UTC), frames tracked per
second over the last 10 s, frames, tracker resets (stamp gaps, time going back, publisher
restarts) and frames with a plausibility warning (units, conventions) on this instance,
tracks, seconds since its last frame.
Every fused vehicle (docs/SERVICE.md, "Vehicle fusion") is listed with its sensors: each
one's condition (ok; PROBATION while it is checked against the others; SILENT, CLOCK or
EXTRINSIC, with why), frames taken, frames kept out, seconds since its last frame and its
median stamp -> receipt latency.
Exit 1 when no instance answered.

{ZENOH_NOTE}

examples:
  simpletrack status                              # the service on this machine
  simpletrack status --mode client --connect tcp/router:7447 --prefix fleet
  simpletrack status --json                       # one ServiceStatus per line
"""


def register(subparsers: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    p = subparsers.add_parser(
        "status",
        help="members of the group on a prefix and the sensors each owns",
        description="Ask every instance on the prefix for its status and print them.",
        formatter_class=argparse.RawDescriptionHelpFormatter,
        epilog=EPILOG,
    )
    p.add_argument("--timeout", type=float, default=2.0, help="seconds to wait for answers (2)")
    p.add_argument("--json", action="store_true", help="print each ServiceStatus as JSON")
    p.add_argument("--sensors", action="store_true", help="list every sensor owned")
    add_client_args(p)
    p.set_defaults(func=run)


def collect(session: zenoh.Session, prefix: str, timeout: float) -> list[ServiceStatus]:
    out = []
    for reply in session.get(Keys(prefix).status("*"), timeout=timeout):
        if reply.ok is None:
            continue
        status = decode_message(reply.ok.payload.to_bytes(), ServiceStatus)
        if not isinstance(status, Rejection):
            out.append(status)
    return sorted(out, key=lambda s: s.instance)


def _stamp(ns: int | None) -> str:
    if ns is None:
        return "-"
    # Whole seconds and milliseconds apart: a float of the nanoseconds rounds .200 to .199.
    t = datetime.fromtimestamp(ns // 1_000_000_000, tz=UTC)
    return t.strftime("%Y-%m-%dT%H:%M:%S.") + f"{ns // 1_000_000 % 1000:03d}Z"


def sensor_line(x: SensorStatus) -> str:
    """One sensor: what it last tracked, how fast it comes, how often its tracker restarted."""
    return (
        f"{x.vehicle}/{x.sensor}  seq={'-' if x.last_seq is None else x.last_seq}"
        f"  stamp={_stamp(x.last_stamp_ns)}  rate={x.rate_hz:.1f}/s  frames={x.frames}"
        f"  resets={x.resets}  implausible={x.implausible_frames}  tracks={x.active_tracks}"
        f"  idle={x.idle_s:.1f}s"
    )


def vehicle_lines(v: VehicleStatus) -> list[str]:
    """A fused vehicle, then each of its sensors; a sensor not ok is named in capitals, with
    why (a silent or flagged sensor is what an operator looks for)."""
    lines = [
        f"{v.vehicle}/@vehicle  seq={'-' if v.seq is None else v.seq}"
        f"  stamp={_stamp(v.last_stamp_ns)}  frames={v.frames}  tracks={v.active_tracks}"
        f"  late={v.late_frames}  reprocessed={v.reprocessed_frames}"
    ]
    for x in v.sensors:
        state = x.state.value if x.state is SensorCondition.OK else x.state.value.upper()
        idle = "-" if x.idle_s is None else f"{x.idle_s:.1f}s"
        latency = "-" if x.latency_s is None else f"{x.latency_s * 1e3:.0f}ms"
        why = f"  ({x.detail})" if x.detail else ""
        lines.append(
            f"  {x.sensor} {state}  seq={'-' if x.last_seq is None else x.last_seq}"
            f"  frames={x.frames}  kept_out={x.flagged_frames}  idle={idle}"
            f"  latency={latency}{why}"
        )
    return lines


def render(statuses: list[ServiceStatus], with_sensors: bool) -> str:
    lines = []
    answered = {s.instance for s in statuses}
    seen = {m for s in statuses for m in s.members}
    for s in statuses:
        tracks = sum(x.active_tracks for x in s.sensors) + sum(v.active_tracks for v in s.vehicles)
        lines.append(
            f"{s.instance}  {'ready' if s.ready else 'NOT READY'}  members={','.join(s.members)}"
            f"  owns={len(s.sensors)}  standby={s.standby_sensors}  tracks={tracks}"
            f"  queue={s.queue_depth}  handoffs in/out={s.handoffs_in}/{s.handoffs_out}"
            f"  failovers={s.failovers}  preset={s.preset}  version={s.version}"
        )
        if with_sensors:
            for x in sorted(s.sensors, key=lambda x: (x.vehicle, x.sensor)):
                lines.append(f"    {sensor_line(x)}")
        for v in sorted(s.vehicles, key=lambda v: v.vehicle):
            lines.extend(f"    {line}" for line in vehicle_lines(v))
    for m in sorted(seen - answered):
        lines.append(f"{m}  silent (a member in some view that did not answer)")
    views = {tuple(s.members) for s in statuses}
    if len(views) > 1:
        lines.append("views differ: the group is changing, or partitioned")
    return "\n".join(lines)


def run(args: argparse.Namespace) -> int:
    prefix = check_prefix(args.prefix)
    if args.timeout <= 0:
        raise UserError(f"--timeout {args.timeout} must be positive")
    options = client_options(args)
    with open_client_session(options) as session:
        if options.mode.value == "peer":
            # Peers route nothing for each other: the members beyond the one connected to
            # are reached once gossip has connected this session to them (milliseconds).
            time.sleep(min(0.5, args.timeout / 2))
        statuses = collect(session, prefix, args.timeout)
    if not statuses:
        print(f"no instance answered on {prefix}/@simpletrack/*/status", file=sys.stderr)
        return 1
    if args.json:
        for s in statuses:
            print(json.dumps(dataclasses.asdict(s)))
    else:
        print(render(statuses, args.sensors))
    return 0


__all__ = ["collect", "register", "render", "run", "sensor_line", "vehicle_lines"]
