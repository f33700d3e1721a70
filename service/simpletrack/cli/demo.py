"""``simpletrack demo``: the service and a simulated fleet on this machine, with a live view."""

from __future__ import annotations

import argparse
import json
import signal
import sys
from pathlib import Path

from pydantic import ValidationError

from simpletrack.cli.errors import UserError
from simpletrack.session import ZenohOptions, add_zenoh_args

EPILOG = """\
Starts the tracking service (preset "wod": vehicle, pedestrian, cyclist, with the demo's
settings of simpletrack.sim.demo_tracker, chosen on seed 1) on an embedded Zenoh
peer listening on a free loopback port, and a simulated fleet: every vehicle drives its own
loop with its sensors (a 360-degree lidar and a front sensor); objects move, turn, hide behind
each other and come and go; the detector adds noise, misses in bursts, false positives, low
scores and duplicate boxes. Each sensor publishes its detections with its pose; a planner-side subscriber
receives the tracks of the whole fleet and scores them against the simulator's ground truth.

The browser view (http://127.0.0.1:8090/ unless --view-port or --no-view; docs/VIEW.md) draws
each sensor's tracks and detections from above, live, as a planner receives them.
The live view (on a terminal) shows per sensor: track frames received / published, frame
rate, end-to-end latency p50/p99 (sensor stamp to planner), active tracks, rejected frames,
and the running MOTA and ID switches. The summary is printed at the end, also when the output
is not a terminal; it scores the tracks next to the raw detections of the same frames (kept
at the preset's score_high, after NMS, without ids) and ends in one line: frames tracked,
latency, MOTA (detections alone), IDS, ids per object. Ctrl-C ends the demo cleanly (exit 0,
with the summary).

Exit code: 0 when tracks came back (or on Ctrl-C); 1 when the service failed or nothing was
tracked; 2 on bad arguments.

examples:
  simpletrack demo                          # until Ctrl-C
  simpletrack demo --duration 30 --vehicles 5 --seed 7
  simpletrack demo --duration 10 --json out/demo.json --record out/demo
  simpletrack plot out/demo/tracks.jsonl --stream veh00/lidar \\
      --truth out/demo/truth.jsonl --out out/demo/veh00-lidar.png
  simpletrack demo --metrics-port 9464      # and: curl -s localhost:9464/metrics
  simpletrack demo --inject-errors 0.02     # 2 % broken frames: watch them get rejected
  simpletrack demo --service external --connect tcp/127.0.0.1:7447 --prefix fleet
"""


def register(subparsers: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    p = subparsers.add_parser(
        "demo",
        help="the service and a simulated fleet with a live view (no router, no data files)",
        description="Run the tracking service and a simulated fleet of vehicles on this machine "
        "and watch what a planner receives, scored against the simulator's ground truth.",
        formatter_class=argparse.RawDescriptionHelpFormatter,
        epilog=EPILOG,
    )
    p.add_argument("--duration", type=float, help="stop after this many seconds (default: Ctrl-C)")
    p.add_argument("--vehicles", type=int, default=3, help="vehicles in the fleet (default 3)")
    p.add_argument("--objects", type=int, default=90, help="objects in the world (default 90)")
    p.add_argument("--seed", type=int, default=0, help="random seed of the world (default 0)")
    p.add_argument("--rate", type=float, default=10.0, help="frames per second per sensor (10)")
    p.add_argument(
        "--service",
        choices=("subprocess", "inprocess", "external"),
        help="run the service as `simpletrack serve` in a child process (default), in this "
        "process (faster start; shares the GIL, so latency tails grow), or use a running one "
        "reached with --connect",
    )
    p.add_argument("--prefix", default="fleet", help="key prefix (default fleet)")
    p.add_argument(
        "--inject-errors",
        type=float,
        default=0.0,
        metavar="FRACTION",
        help="send this share of frames broken (NaN box) to show rejections (default 0)",
    )
    p.add_argument("--record", type=Path, metavar="DIR", help="write tracks.jsonl and truth.jsonl")
    p.add_argument("--json", type=Path, metavar="FILE", help="write the summary as JSON")
    p.add_argument(
        "--metrics-port", type=int, default=0, help="the service's /metrics port (default 0: off)"
    )
    p.add_argument("--service-log", type=Path, metavar="FILE", help="the service's log file")
    p.add_argument("--no-live", action="store_true", help="no live view, even on a terminal")
    p.add_argument(
        "--view-port",
        type=int,
        default=8090,
        help="port of the bird's-eye view in the browser (default 8090; taken: any free one; "
        "0: any free one)",
    )
    p.add_argument("--no-view", action="store_true", help="no browser view")
    p.add_argument(
        "--mcap",
        type=Path,
        metavar="FILE",
        help="record the fleet's detections, tracks and errors to this MCAP file (replay it "
        "with `simpletrack replay mcap FILE`)",
    )
    p.add_argument(
        "--ros2",
        nargs="?",
        const=True,
        type=Path,
        metavar="BAG",
        help="with --mcap: also a ROS 2 bag of the same frames as Autoware DetectedObjects and "
        "TrackedObjects (default: the --mcap file with .ros2.mcap; docs/ROS2.md, 'Recordings')",
    )
    add_zenoh_args(p)
    p.set_defaults(func=run)


def _options(args: argparse.Namespace) -> object:
    from simpletrack.sim.demo import DemoOptions, ServiceMode
    from simpletrack.sim.fusion_sensors import fusion_sensors
    from simpletrack.sim.simulator import SimConfig

    if args.duration is not None and args.duration <= 0:
        raise UserError(f"--duration {args.duration:g} must be positive")
    if not 0.0 <= args.inject_errors <= 1.0:
        raise UserError(f"--inject-errors {args.inject_errors:g} must be between 0 and 1")
    if not 0 <= args.metrics_port <= 65535:
        raise UserError(f"--metrics-port {args.metrics_port} is not a port number")
    if not 0 <= args.view_port <= 65535:
        raise UserError(f"--view-port {args.view_port} is not a port number")
    if args.mcap is not None and not args.mcap.parent.is_dir():
        raise UserError(f"--mcap {args.mcap}: no folder {args.mcap.parent}")
    if args.ros2 is not None and args.mcap is None:
        raise UserError("--ros2 records beside --mcap: give --mcap FILE too")
    if args.ros2 is True:
        from simpletrack.mcap.ros2 import default_path

        args.ros2 = default_path(args.mcap)
    if args.ros2 is not None and not args.ros2.parent.is_dir():
        raise UserError(f"--ros2 {args.ros2}: no folder {args.ros2.parent}")
    try:
        sim = SimConfig(
            seed=args.seed,
            vehicles=args.vehicles,
            objects=args.objects,
            rate_hz=args.rate,
            sensors=fusion_sensors(),
        )
    except ValidationError as exc:
        first = exc.errors(include_url=False)[0]
        field = {"rate_hz": "rate"}.get(str(first["loc"][0]), str(first["loc"][0]))
        raise UserError(f"--{field} {first['input']!r}: {first['msg']}") from None
    mode = ServiceMode(args.service) if args.service else None
    if mode is None:
        mode = ServiceMode.EXTERNAL if args.zenoh_connect else ServiceMode.SUBPROCESS
    client = None
    listen = None
    if mode is ServiceMode.EXTERNAL:
        if not args.zenoh_connect:
            raise UserError("--service external needs --connect ENDPOINT (where the service is)")
        try:
            client = ZenohOptions.from_args(args)
        except ValueError as exc:
            raise UserError(str(exc)) from None
    else:
        if args.zenoh_connect or args.zenoh_mode == "client":
            raise UserError(
                "--connect/--mode client reach an external service: add --service external"
            )
        listens = args.zenoh_listen or []
        if len(listens) > 1:
            raise UserError("give at most one --listen endpoint for the demo's service")
        listen = listens[0] if listens else None
    return DemoOptions(
        sim=sim,
        duration=args.duration,
        service=mode,
        listen=listen,
        client=client,
        prefix=args.prefix,
        inject_errors=args.inject_errors,
        record=args.record,
        metrics_port=args.metrics_port,
        service_log=args.service_log,
        view_port=None if args.no_view else args.view_port,
        mcap=args.mcap,
        ros2=args.ros2,
    )


def run(args: argparse.Namespace) -> int:
    import zenoh
    from rich.console import Console
    from rich.live import Live

    from simpletrack.sim.demo import DemoOptions, DemoResult, FleetDemo
    from simpletrack.sim.demo_view import live_view, summary_json, summary_lines

    options = _options(args)
    assert isinstance(options, DemoOptions)
    console = Console()
    demo = FleetDemo(options)
    previous = {s: signal.signal(s, demo.request_stop) for s in (signal.SIGINT, signal.SIGTERM)}
    use_live = console.is_terminal and not args.no_live
    live = Live(console=console, auto_refresh=False, transient=True) if use_live else None
    last_plain = [-1.0]

    def on_tick(result: DemoResult) -> None:
        if live is not None:
            live.update(live_view(result, options), refresh=True)
        elif last_plain[0] < 0:
            last_plain[0] = 0.0
            sim = options.sim
            print(
                f"demo: running: {sim.vehicles} vehicles x {len(sim.sensors)} sensors publishing "
                f"to the service on {result.endpoint}; "
                + (f"{options.duration:g} s" if options.duration else "Ctrl-C to stop"),
                flush=True,
            )
            if result.view_url:
                print(f"demo: live view in the browser: {result.view_url}", flush=True)
        elif result.elapsed - last_plain[0] >= 5.0:
            # Not a terminal: a progress line every 5 s instead of the live table.
            last_plain[0] = result.elapsed
            st = result.stats
            print(
                f"demo: {result.elapsed:.0f} s, {st.tracked}/{st.sent} frames tracked, "
                f"{st.tracks_now} fused tracks, fused MOTA {st.scores.counts('fused').mota:.3f}",
                flush=True,
            )

    try:
        if live is not None:
            live.start()
        try:
            result = demo.run(on_tick)
        finally:
            if live is not None:
                live.stop()
    except (RuntimeError, zenoh.ZError, OSError) as exc:
        print(f"simpletrack demo: error: {exc}", file=sys.stderr)
        return 1
    finally:
        for s, handler in previous.items():
            signal.signal(s, handler)
    if use_live:
        console.print(live_view(result, options))
    for line in summary_lines(result, options):
        print(line)
    if args.json is not None:
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text(json.dumps(summary_json(result, options), indent=1) + "\n")
        print(f"  wrote {args.json}")
    if args.mcap is not None:
        print(f"  wrote {args.mcap} (replay it: simpletrack replay mcap {args.mcap})")
    if args.ros2 is not None:
        print(f"  wrote {args.ros2} (a ROS 2 bag: rosbags, ros2 bag play)")
    sys.stdout.flush()
    if result.stopped_by == "interrupted":
        return 0  # Ctrl-C is the documented way to end it
    return 0 if result.stats.tracked > 0 else 1
