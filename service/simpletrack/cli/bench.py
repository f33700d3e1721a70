"""``simpletrack bench core|service``: the tracker's cost curve, the service's latency and
capacity. Figures are printed, written as JSON (``--json``) and drawn (``--plot-dir``)."""

from __future__ import annotations

import argparse
import json
import sys
from collections.abc import Callable
from pathlib import Path
from typing import Any

from simpletrack.cli.errors import UserError
from simpletrack.datasets.paths import DATA, MissingData, data_dir, default_help

DATA_HELP = (
    f"the datasets' folder, with nuscenes/centerpoint_val/ and kitti/ ({default_help(DATA)})"
)

EPILOG = """\
Real frames come from --data, else $SIMPLETRACK_DATA (the folder holding nuscenes/ and kitti/);
there is no default folder. Synthetic loads need neither.

examples:
  export SIMPLETRACK_DATA=~/datasets   # holds nuscenes/centerpoint_val/ and kitti/

  # the tracker alone: all 150 nuScenes scenes, the 10 KITTI sequences, the scaling sweep
  simpletrack bench core --json out/bench-core.json --plot-dir out/

  # a quick look: 10 scenes, 2 KITTI sequences, a short sweep
  simpletrack bench core --scenes 10 --kitti-sequences 2 --sizes 10,100,500

  # the running service under 1..500 sensors at 10 Hz, with the Zenoh echo floor
  simpletrack bench service --json out/bench-service.json --plot-dir out/

  # profile the service with py-spy while it is under load (pip install py-spy)
  simpletrack bench service --sensors 1,10,20 --profile out/profiles/
  # the interpreter lock's time per frame (py-spy --gil), e.g. against another revision's
  simpletrack bench service --sensors 60 --seconds 25 --no-echo --profile out/gil --profile-gil

Figures depend on the machine and on what else runs on it: quote medians and ratios from one
run, with the load average the JSON records. docs/BENCHMARKS.md explains every figure.
"""

CORE_EPILOG = """\
what it measures:
  per load (nuScenes val, preset nuscenes, 7 classes in one tracker per scene; KITTI train,
  preset kitti, Car alone and all 3 classes in one tracker per sequence): frames/s and the
  per-frame latency of Tracker.step (files are parsed first, not timed); then, in a second
  pass with timing shims on the functions step calls, ms per frame in each stage (nms,
  step: an ordinary frame's prediction-to-output in one compiled call; and for the frames
  it does not take: predict, cost_matrix, assignment, advance; other).
  The sweep: synthetic frames of N cars (one class) and as many live tracks, per-frame time
  against N on a log-log plot with the fitted growth exponent.
  The speed-up against the reference uses its authors' own measurement on this machine kind
  (reference/README.md of the datasets' folder: median 0.35 s per nuScenes frame, p99 1.6 s).
  Real frames: --data, else $SIMPLETRACK_DATA; --scenes 0 --kitti-sequences 0 needs neither.

examples:
  simpletrack bench core --data ../shared/data
  simpletrack bench core --scenes 20 --kitti-sequences 0 --sizes 10,100,1000 --json core.json
  simpletrack bench core --scenes 0 --kitti-sequences 0 --plot-dir plots/   # sweep only
  simpletrack bench core --scenes 10 --kitti-sequences 2 --sizes 100,1000 --against main

against another revision (--against REF):
  REF's files are taken from git (git archive into a temporary directory, removed afterwards)
  and the same benchmark runs --rounds times with this code and with REF's, alternating, each
  run a fresh `simpletrack bench core` process with its own code on PYTHONPATH. Passed through
  to both sides: --data --scenes --kitti-sequences --sizes --sweep-frames --sweep-budget (so
  REF's bench must know them; every revision since the service/schemas/clients layout does).
  Printed: each figure's median over the rounds for both sides and the ratio, > 1 when this
  code is better (REF/this for times, this/REF for frames/s); "–" where one side lacks the
  figure. --json writes both sides' documents and the ratios; --plot-dir is refused.
  A round is two runs of the command without --against (the defaults: ~2 min each).
"""

SCALE_EPILOG = """\
what it measures (for each member count M of --instances):
  capacity: the service benchmark's search (same load generator, same pass/saturation rules)
  against M `simpletrack serve --preset nuscenes` processes on one prefix, peer mode on
  127.0.0.1, each on its own port and connected to the others, the load generator connected
  to all; a fresh group per step. Then, for M >= 2, two runs of --fault-sensors sensors for
  --duration s, one member hit half-way: failover (SIGKILL) and hand-off (SIGTERM). For the
  sensors whose last track frame before the fault came from that member (TrackFrame.instance):
  max and median time from the fault to their first track frame from another member (it
  includes the wait for each sensor's next frame: at low --rate, read also how long after
  its put the first frame after the fault was answered); over
  the frames put from 1 s before the fault on: how many got no track frame, and how many more
  than one (a failover publishes the dead member's last frame of each moved sensor once
  more: counted apart, "victim's last again"). The other sensors (served by a survivor
  before the fault): their p99 over the frames put 3 s before and 3 s after it (did taking
  the victim's sensors over hold them back?). Each member's resident memory just before the
  fault, the survivors' at the end; the load generator's longest put lag (a vehicle's put to
  a member dying under it can block). The members form one group (docs/SCALE.md):
  each sensor is tracked by one member, so before a fault every frame gets one answer
  ("answers/frame before") and capacity grows with M as far as the machine's cores do (the
  members and the load generator share them). With --subscribe owned (the default) each
  member subscribes to the sensors it owns or stands by for only; --subscribe wide: every
  member hears every frame and every tracks message.
  The load generator: as in `bench service` (--generator-processes, --generator-cpus; the
  capacity table's "generator cores at max"; a generator-limited step stops the search).

examples:
  simpletrack bench scale --out out/scale/
  simpletrack bench scale --instances 1,2 --sensors 2 --duration 2 --source synthetic  # smoke
  # 16 cores: the members on CPUs 4-15, the load generator (4 processes) on 0-3
  taskset -c 4-15 simpletrack bench scale --instances 1,4,8 --source synthetic \\
      --sensors 80,160,320,640,1000 --generator-processes 4 --generator-cpus 0-3
"""

SERVICE_EPILOG = """\
what it measures (one step per sensor count S, each with a fresh server):
  a spawned load generator publishes S sensors x 10 Hz of real nuScenes frames (cycled; all
  10 detector classes, the 3 untracked ones dropped by the service's ignore_classes) to a
  fresh `simpletrack serve --preset nuscenes` on 127.0.0.1, and times each track frame from
  just before `put` to its receipt (one process, one monotonic clock). Reported: p50/p99/max,
  delivered frames/s, the server's CPU per frame (/proc/<pid>/stat over the window), frames
  refused/dropped (errors key and /metrics) and never answered. The same load against an
  echo process (no tracker) is the Zenoh floor. A step passes with p99 < --p99-limit and
  nothing refused, dropped or lost; S stops growing once a step saturates (a frame refused,
  dropped or lost, or the median over --p99-limit: the server fell behind).

the load generator (--generator-processes N, --generator-cpus LIST):
  one process by default; N processes split the sensors into N contiguous blocks, each with
  its own Zenoh session publishing its block and hearing only its block's answers (latency
  is still two readings of one clock, in the process that published the frame). Reported
  per step: "loadgen cores" (all processes' CPU over the window), "busiest" (the busiest
  process's cores), "interp" (the busiest process's Python threads, which share one
  interpreter lock), "lag p99 ms" (how late puts started against their schedule); per
  process in the JSON (generator.per_process, with the answer lag: the service's
  published_ns to the callback). GENERATOR-LIMITED: an interpreter over 0.9 cores, the
  --generator-cpus over 90 % busy, or a put lag or answer lag p99 over 10 ms (puts not
  blocked): the step measured the generator, not the service; it does not pass, is no
  capacity figure, and S stops growing there.

examples:
  simpletrack bench service
  simpletrack bench service --sensors 1,5,10,20 --seconds 10 --json service.json --plot-dir plots/
  simpletrack bench service --sensors 2 --seconds 1 --source synthetic --no-echo   # smoke
  simpletrack bench service --sensors 1,10,20 --seconds 5 --no-echo --against main
  # 16 cores: the service on CPUs 4-15, the load generator (4 processes) on 0-3
  taskset -c 4-15 simpletrack bench service --sensors 250,500,1000 --source synthetic \\
      --no-echo --generator-processes 4 --generator-cpus 0-3

against another revision (--against REF):
  as for `bench core --against`: REF's files from git into a temporary directory (removed
  afterwards), then --rounds rounds of this code's and REF's `simpletrack bench service`,
  alternating, each a fresh process whose server and load generator run that side's code.
  Passed through to both sides: --sensors --seconds --warmup --rate --workers --queue-size
  --source --data --synthetic-boxes --p99-limit --budget --no-echo, and the --generator-*
  and --heartbeat flags when given (REF must know them); --plot-dir is refused, --profile
  too unless --server-only. With --server-only both sides' rounds run this code's bench and
  load generator and only the service process runs REF's code: one generator for both, and
  --profile DIR --profile-gil profiles each run's service (DIR/this-N, DIR/ref-N) and compares
  the interpreter lock's time per frame. A round is two full service benchmarks: with the
  defaults up to ~2 x 8 min, so the default is 2 rounds and a comparison is best made on a few
  steps (--sensors 1,10,20 --seconds 5 --no-echo: ~1 min a round). Ratio > 1 when this code
  is better (REF/this for latencies and CPU per frame, this/REF for frames/s, sensors and
  streams per core).
"""


def _int_list(text: str, what: str, low: int, high: int) -> tuple[int, ...]:
    try:
        values = tuple(int(v) for v in text.split(",") if v.strip())
    except ValueError:
        raise UserError(f"{what} {text!r} must be a comma-separated list of integers") from None
    if not values or any(not (low <= v <= high) for v in values):
        raise UserError(f"{what} {text!r}: every value must be in {low}..{high}")
    if list(values) != sorted(set(values)):
        raise UserError(f"{what} {text!r} must be increasing, without repeats")
    return values


def _positive(value: float, what: str, high: float) -> float:
    if not (0 < value <= high):
        raise UserError(f"{what} {value:g} must be > 0 and <= {high:g}")
    return value


def register(subparsers: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    p = subparsers.add_parser(
        "bench",
        help="benchmarks: the tracker core's cost curve, the service's latency and capacity",
        description="Measure the tracker core (bench core) or the running service (bench "
        "service); print a table, write every figure as JSON and draw PNG plots.",
        formatter_class=argparse.RawDescriptionHelpFormatter,
        epilog=EPILOG,
    )
    sub = p.add_subparsers(dest="bench", metavar="WHAT", required=True)

    core = sub.add_parser(
        "core",
        help="the tracker alone on nuScenes, KITTI and a synthetic scaling sweep",
        description="Frames/s, per-frame latency and time per stage of Tracker.step.",
        formatter_class=argparse.RawDescriptionHelpFormatter,
        epilog=CORE_EPILOG,
    )
    core.add_argument(
        "--data",
        type=Path,
        metavar="FOLDER",
        help=DATA_HELP,
    )
    core.add_argument(
        "--scenes",
        type=int,
        default=150,
        help="nuScenes val scenes to run, 0 to skip (default all 150)",
    )
    core.add_argument(
        "--kitti-sequences",
        type=int,
        default=10,
        help="KITTI train sequences to run, 0 to skip (default all 10)",
    )
    core.add_argument(
        "--sizes",
        default="10,50,100,200,500,1000",
        help="boxes per frame of the sweep, or 'none' (default 10,...,1000)",
    )
    core.add_argument(
        "--sweep-frames",
        type=int,
        default=20,
        help="timed frames per sweep size (fewer past --sweep-budget; default 20)",
    )
    core.add_argument(
        "--sweep-budget",
        type=float,
        default=5.0,
        help="seconds of timed frames per sweep size, at least 3 frames (default 5)",
    )
    core.add_argument(
        "--options",
        help="comma-separated cross-validation candidates (simpletrack.eval.cv.ALL_CANDIDATES, "
        "e.g. ctra,immortal): each real load is timed again with the candidate's changes in "
        "every class, as '<load>+<name>'",
    )
    core.add_argument("--json", type=Path, help="write every figure to this JSON file")
    core.add_argument("--plot-dir", type=Path, help="write core_scaling.png and core_stages.png")
    _add_against_args(core, rounds=3)
    core.set_defaults(func=run_core)

    worker = sub.add_parser(
        "worker",
        help="one service worker's CPU per frame, in-process, by stage",
        description="A real service (its session, custody, registry, outbox, metrics; one "
        "worker) fed frames by the bench's own thread as its worker thread feeds them from its "
        "queue: the worker's CPU per frame (thread time), then the same path by stage. No "
        "load generator, no receive, no thread hop: steadier than bench service on a shared "
        "machine, and blind to what those cost.",
    )
    worker.add_argument(
        "--sensors", type=int, default=60, help="sensors, each a frame per turn (default 60)"
    )
    worker.add_argument(
        "--frames", type=int, default=60, help="frames per sensor in each pass (default 60)"
    )
    worker.add_argument(
        "--warmup", type=int, default=20, help="frames per sensor before the passes (default 20)"
    )
    _add_source_args(worker)
    worker.add_argument("--json", type=Path, help="write every figure to this JSON file")
    worker.set_defaults(func=run_worker)

    svc = sub.add_parser(
        "service",
        help="latency, CPU and capacity of `simpletrack serve` under a load generator",
        description="A real service and a separate load-generator process on 127.0.0.1.",
        formatter_class=argparse.RawDescriptionHelpFormatter,
        epilog=SERVICE_EPILOG,
    )
    svc.add_argument(
        "--sensors",
        default="1,10,50,100,200,500",
        help="sensor counts to step through (default 1,10,50,100,200,500)",
    )
    svc.add_argument(
        "--seconds",
        type=float,
        default=20.0,
        help="measured seconds per step, after the warm-up (default 20)",
    )
    svc.add_argument(
        "--warmup", type=float, default=1.0, help="seconds of load before measuring (default 1)"
    )
    svc.add_argument("--rate", type=float, default=10.0, help="frames/s per sensor (default 10)")
    svc.add_argument("--workers", type=int, default=2, help="service worker threads (default 2)")
    svc.add_argument(
        "--queue-size", type=int, default=64, help="service frames queued per worker (default 64)"
    )
    svc.add_argument(
        "--source",
        choices=("nuscenes", "synthetic"),
        default="nuscenes",
        help="real nuScenes frames (default) or synthetic ones (no data needed)",
    )
    svc.add_argument(
        "--data",
        type=Path,
        metavar="FOLDER",
        help=DATA_HELP,
    )
    svc.add_argument(
        "--synthetic-boxes",
        type=int,
        default=128,
        help="boxes per synthetic frame (default 128, the nuScenes mean)",
    )
    svc.add_argument(
        "--p99-limit",
        type=float,
        default=50.0,
        help="a step passes with p99 under this many ms (default 50)",
    )
    svc.add_argument(
        "--budget",
        type=float,
        default=420.0,
        help="no new step starts past this many seconds in total (default 420)",
    )
    svc.add_argument("--no-echo", action="store_true", help="skip the Zenoh echo floor")
    svc.add_argument(
        "--fused",
        action="store_true",
        help="fused vehicles instead of sensors: each step's count is vehicles, each a lidar "
        "(the scene's frames) and a front camera (its view of them, half a period later), "
        "answered on the vehicle's key; latency: each frame's put to the vehicle message "
        "answering it (docs/SERVICE.md, Vehicle fusion)",
    )
    svc.add_argument(
        "--profile",
        type=Path,
        metavar="DIR",
        help="record each service step with py-spy into DIR (needs py-spy)",
    )
    svc.add_argument(
        "--profile-gil",
        action="store_true",
        help="with --profile: record only the samples holding the interpreter lock (py-spy "
        "--gil) and report the lock's time per frame",
    )
    _add_generator_args(svc)
    svc.add_argument("--json", type=Path, help="write every figure to this JSON file")
    svc.add_argument(
        "--plot-dir", type=Path, help="write service_latency_cdf.png and service_capacity.png"
    )
    _add_against_args(svc, rounds=2)
    svc.add_argument(
        "--server-only",
        action="store_true",
        help="with --against: REF's rounds run this code's bench and load generator too, only "
        "the service process runs REF's code (one generator for both sides; --profile DIR "
        "then profiles each run's service into DIR/this-N, DIR/ref-N)",
    )
    svc.set_defaults(func=run_service)

    scale = sub.add_parser(
        "scale",
        help="capacity against group members; failover and hand-off times",
        description="Capacity of 1, 2, 4 ... `simpletrack serve` members on one prefix, and what "
        "killing (SIGKILL) or stopping (SIGTERM) one member costs its sensors.",
        formatter_class=argparse.RawDescriptionHelpFormatter,
        epilog=SCALE_EPILOG,
    )
    scale.add_argument(
        "--instances", default="1,2,4", help="member counts to measure (default 1,2,4)"
    )
    scale.add_argument(
        "--sensors",
        default="1,5,10,15,20,30,40,60,80",
        help="sensor counts of the capacity search (default 1,5,10,15,20,30,40,60,80)",
    )
    scale.add_argument(
        "--duration",
        type=float,
        default=10.0,
        help="measured seconds per capacity step and per fault run (default 10)",
    )
    scale.add_argument(
        "--warmup", type=float, default=1.0, help="seconds of load before measuring (default 1)"
    )
    scale.add_argument("--rate", type=float, default=10.0, help="frames/s per sensor (default 10)")
    scale.add_argument(
        "--subscribe",
        choices=("wide", "owned"),
        default="owned",
        help="the members' subscribe setting (default owned, the service's: the load generator "
        "publishes with advanced publishers, whose tokens the members find sensors by; wide: "
        "every member hears every frame)",
    )
    scale.add_argument(
        "--workers", type=int, default=2, help="worker threads per member (default 2)"
    )
    scale.add_argument(
        "--fused",
        action="store_true",
        help="fused vehicles instead of sensors, as bench service --fused: --sensors and "
        "--fault-sensors count vehicles (a lidar and a front camera each), the members fuse "
        "them; a fault's figures are per sensor, each answered by its vehicle's messages",
    )
    scale.add_argument(
        "--fault-sensors",
        type=int,
        default=10,
        help="sensors streaming during the fault runs (default 10; 0: no fault runs)",
    )
    _add_source_args(scale)
    scale.add_argument(
        "--p99-limit",
        type=float,
        default=50.0,
        help="a step passes with p99 under this many ms (default 50)",
    )
    scale.add_argument(
        "--budget",
        type=float,
        default=300.0,
        help="no new capacity step starts past this many seconds per member count (default 300)",
    )
    _add_generator_args(scale)
    scale.add_argument(
        "--out", type=Path, metavar="DIR", help="write scale.json and scale_capacity.png here"
    )
    scale.set_defaults(func=run_scale)

    fuzz = sub.add_parser(
        "fuzz",
        help="valid and mutated frames through a real service: every frame answered, nothing broken",
        description="A real `simpletrack serve` (lossless backpressure) and many sensors sending "
        "valid frames mixed with mutated ones (flipped bytes, truncation, odd values, NaN/inf and "
        "huge numbers in columns, replays, wrong keys). Exits 1 unless every frame got exactly "
        "one answer, no answer was non-finite or undecodable, and the service neither died nor "
        "logged a traceback.",
    )
    fuzz.add_argument("--frames", type=int, default=100_000, help="frames to send (default 100000)")
    fuzz.add_argument(
        "--sensors", type=int, default=20, help="sensors to spread them over (default 20)"
    )
    fuzz.add_argument(
        "--mutated", type=float, default=0.5, help="share of frames mutated (default 0.5)"
    )
    fuzz.add_argument("--seed", type=int, default=0, help="random seed (default 0)")
    fuzz.add_argument("--json", type=Path, help="write the report to this JSON file")
    fuzz.set_defaults(func=run_fuzz)

    faults = sub.add_parser(
        "faults",
        help="the fleet's ordinary faults end to end: what a planner sees, ids kept, bystanders",
        description="Each scenario streams cars at 10 Hz from a victim and a bystander sensor "
        "through a real service (behind a real router process where the fault needs one), "
        "breaks something and prints frames sent / tracked / refused / dropped / announced / "
        "recovered, ids kept across the fault, the bystander's latency and loss, peak memory.",
    )
    faults.add_argument(
        "--scenarios", default="all", help="comma-separated scenario names (default all)"
    )
    faults.add_argument("--json", type=Path, help="write the results to this JSON file")
    faults.set_defaults(func=run_faults)


def _add_against_args(parser: argparse.ArgumentParser, rounds: int) -> None:
    parser.add_argument(
        "--against",
        metavar="REF",
        help="also run REF's code (a git revision: main, HEAD~3, a commit) in alternating "
        "rounds and print each figure's ratio (see below)",
    )
    parser.add_argument(
        "--rounds",
        type=int,
        default=rounds,
        help=f"with --against: runs of each side, alternating (default {rounds})",
    )


def _against(args: argparse.Namespace, bench: str, options: list[str]) -> int:
    """``--against``: both sides' runs, the comparison printed and written."""
    from simpletrack.bench.against import AgainstError, against_table, compare
    from simpletrack.bench.stats import machine

    if not (1 <= args.rounds <= 50):
        raise UserError(f"--rounds {args.rounds} must be in 1..50")
    server_only = bool(getattr(args, "server_only", False))
    profile: Path | None = getattr(args, "profile", None)  # bench service: with --server-only
    if args.plot_dir is not None:
        raise UserError("--plot-dir does not combine with --against")

    def per_run(tag: str) -> list[str]:
        if profile is None:
            return []
        return ["--profile", str(profile / tag), *(["--profile-gil"] if args.profile_gil else [])]

    _out_paths(args)
    before = machine()
    try:
        result = compare(
            "core" if bench == "core" else "service",
            options,
            args.against,
            args.rounds,
            progress=lambda m: print(m, file=sys.stderr, flush=True),
            server_only=server_only,
            per_run=per_run,
        )
    except AgainstError as exc:
        raise UserError(str(exc)) from None
    doc = {
        "command": "simpletrack " + " ".join(sys.argv[1:]),
        "machine_before": before,
        "machine_after": machine(),
        **result,
    }
    print(against_table(doc))
    _write_json(args.json, doc)
    return 0


def _add_source_args(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--source",
        choices=("nuscenes", "synthetic"),
        default="nuscenes",
        help="real nuScenes frames (default) or synthetic ones (no data needed)",
    )
    parser.add_argument(
        "--data",
        type=Path,
        metavar="FOLDER",
        help=DATA_HELP,
    )
    parser.add_argument(
        "--synthetic-boxes",
        type=int,
        default=128,
        help="boxes per synthetic frame (default 128, the nuScenes mean)",
    )


def _add_generator_args(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--generator-processes",
        type=int,
        default=1,
        metavar="N",
        help="load-generator processes (default 1): the sensors split into N contiguous "
        "blocks, each process with its own Zenoh session publishing its block and timing "
        "its block's answers (one clock per process); one process fell behind at 320 "
        "sensors at 10 Hz on a 16-core host",
    )
    parser.add_argument(
        "--generator-cpus",
        metavar="LIST",
        help="run every load-generator process on these CPUs only, e.g. 0-3 or 0,1,2,3: "
        "a fixed budget for the generator, the service kept off it by running the bench "
        "under taskset on the other CPUs (taskset -c 4-15 simpletrack bench ... "
        "--generator-cpus 0-3); default: not pinned",
    )
    parser.add_argument(
        "--heartbeat",
        type=float,
        default=None,
        metavar="SECONDS",
        help="the load generator's publishers send a miss-detection heartbeat this often "
        "(default 0.5, DetectionPublisher's heartbeat_s), whatever their rate, to each "
        "member subscribed to them",
    )


def _generator(args: argparse.Namespace) -> tuple[int, tuple[int, ...]]:
    """--generator-processes and --generator-cpus, checked against this machine."""
    from simpletrack.bench.generators import parse_cpu_list, usable_cpus

    if not (1 <= args.generator_processes <= 64):
        raise UserError(f"--generator-processes {args.generator_processes} must be in 1..64")
    if args.generator_cpus is None:
        return args.generator_processes, ()
    try:
        cpus = parse_cpu_list(args.generator_cpus, usable_cpus())
    except ValueError as exc:
        raise UserError(f"--generator-cpus {args.generator_cpus!r}: {exc}") from None
    return args.generator_processes, cpus


def _heartbeat(args: argparse.Namespace) -> float:
    from simpletrack.client.publisher import DEFAULT_HEARTBEAT_S

    if args.heartbeat is None:
        return DEFAULT_HEARTBEAT_S
    if not (0.01 <= args.heartbeat <= 3600):
        raise UserError(f"--heartbeat {args.heartbeat:g} must be in 0.01..3600 seconds")
    return float(args.heartbeat)


def _generator_option(args: argparse.Namespace) -> list[str]:
    """The generator flags for REF's run (--against), only where given: an older REF knows
    none of them."""
    out = []
    if args.heartbeat is not None:
        out += ["--heartbeat", repr(args.heartbeat)]
    if args.generator_processes != 1:
        out += ["--generator-processes", str(args.generator_processes)]
    if args.generator_cpus is not None:
        out += ["--generator-cpus", args.generator_cpus]
    return out


def _data(given: Path | None, alternative: str) -> Path:
    """The datasets' folder of a run on real frames: --data, else $SIMPLETRACK_DATA."""
    try:
        return data_dir(given, DATA)
    except MissingData as exc:
        raise UserError(f"{exc}; {alternative}") from None


def _data_option(data: Path | None) -> tuple[str, ...]:
    """--data for REF's run (--against): the folder this run reads, if it reads one."""
    return () if data is None else ("--data", str(data.resolve()))


def _out_paths(args: argparse.Namespace) -> None:
    for path in (args.json.parent if args.json else None, args.plot_dir):
        if path is not None:
            try:
                path.mkdir(parents=True, exist_ok=True)
            except OSError as exc:
                raise UserError(f"cannot create {path}: {exc.strerror}") from None


def drawn(draw: Callable[[], list[Path]]) -> list[Path]:
    """The plots ``draw`` wrote; none when matplotlib is missing, said in one line: the run's
    figures still go to its JSON (a long benchmark on a bare host is not lost to its PNGs)."""
    try:
        written = draw()
    except ModuleNotFoundError as exc:
        from simpletrack.cli.main import extra_hint

        hint = extra_hint(exc.name)
        if hint is None:
            raise
        print(f"simpletrack bench: no plots drawn: {hint}", file=sys.stderr)
        return []
    for p in written:
        print(f"wrote {p}")
    return written


def _progress(message: str) -> None:
    print(message, file=sys.stderr, flush=True)


def _report(benchmark: str, before: dict[str, Any], result: dict[str, Any]) -> dict[str, Any]:
    """A run's JSON: what ran and how, the machine before and after, then every figure."""
    from simpletrack.bench.stats import machine

    return {
        "benchmark": benchmark,
        "command": "simpletrack " + " ".join(sys.argv[1:]),
        "machine_before": before,
        "machine_after": machine(),
        **result,
    }


def _write_json(path: Path | None, doc: dict[str, Any]) -> None:
    if path is not None:
        path.write_text(json.dumps(doc, indent=1) + "\n")
        print(f"wrote {path}")


def _candidate_names(text: str | None) -> tuple[str, ...]:
    """--options: cross-validation candidates by name (eval/cv.py), checked."""
    if text is None:
        return ()
    from simpletrack.eval.cv import ALL_CANDIDATES

    known = [c.name for c in ALL_CANDIDATES]
    names = tuple(n.strip() for n in text.split(",") if n.strip())
    unknown = [n for n in names if n not in known]
    if unknown or not names:
        raise UserError(
            f"--options: unknown candidate(s) {', '.join(unknown) or '(none given)'}; "
            f"known: {', '.join(known)}"
        )
    return names


# ----------------------------------------------------------------------------- core
def run_core(args: argparse.Namespace) -> int:
    from simpletrack.bench import plots
    from simpletrack.bench.core import CoreOptions
    from simpletrack.bench.core import run_core as bench
    from simpletrack.bench.report import core_tables
    from simpletrack.bench.stats import machine

    if not (0 <= args.scenes <= 150):
        raise UserError(f"--scenes {args.scenes} must be in 0..150")
    if not (0 <= args.kitti_sequences <= 10):
        raise UserError(f"--kitti-sequences {args.kitti_sequences} must be in 0..10")
    sizes = () if args.sizes == "none" else _int_list(args.sizes, "--sizes", 1, 20000)
    if args.sweep_frames < 3:
        raise UserError(f"--sweep-frames {args.sweep_frames} must be at least 3")
    _positive(args.sweep_budget, "--sweep-budget", 3600)
    options = _candidate_names(args.options)
    if options and args.against is not None:
        raise UserError("--options times this code only: drop --against (or --options)")
    if args.scenes or args.kitti_sequences:
        args.data = _data(args.data, "or --scenes 0 --kitti-sequences 0 for the sweep alone")
    if args.scenes and not (args.data / "nuscenes" / "centerpoint_val").is_dir():
        raise UserError(
            f"no nuScenes detections under {args.data / 'nuscenes'}: give --data, "
            "or --scenes 0 to skip them"
        )
    if args.kitti_sequences and not (args.data / "kitti" / "detections").is_dir():
        raise UserError(
            f"no KITTI detections under {args.data / 'kitti'}: give --data, "
            "or --kitti-sequences 0 to skip them"
        )
    if args.against is not None:
        return _against(
            args,
            "core",
            [
                *_data_option(args.data),
                *("--scenes", str(args.scenes)),
                *("--kitti-sequences", str(args.kitti_sequences)),
                *("--sizes", args.sizes),
                *("--sweep-frames", str(args.sweep_frames)),
                *("--sweep-budget", repr(args.sweep_budget)),
            ],
        )
    _out_paths(args)
    before = machine()
    opts = CoreOptions(
        args.data or Path(),
        args.scenes,
        args.kitti_sequences,
        sizes,
        args.sweep_frames,
        args.sweep_budget,
        options,
    )
    result = bench(opts, progress=_progress)
    doc = _report("core", before, result)
    print(core_tables(doc))
    if args.plot_dir is not None:
        plot_dir = args.plot_dir

        def draw() -> list[Path]:
            written = []
            if result["sweep"]:
                written.append(plots.core_scaling(result["sweep"], plot_dir / "core_scaling.png"))
            if result["loads"]:
                written.append(plots.core_stages(result["loads"], plot_dir / "core_stages.png"))
            return written

        doc["plots"] = [str(p) for p in drawn(draw)]
    _write_json(args.json, doc)
    return 0


# ----------------------------------------------------------------------------- worker
def run_worker(args: argparse.Namespace) -> int:
    from simpletrack.bench.stats import machine
    from simpletrack.bench.worker import WorkerOptions, run_worker_bench, worker_table

    data = _scenes_data(args.data) if args.source == "nuscenes" else None
    try:
        opts = WorkerOptions(
            args.sensors, args.frames, args.warmup, args.source, data, args.synthetic_boxes
        )
    except ValueError as exc:
        raise UserError(f"bench worker: {exc}") from None
    _out_paths(argparse.Namespace(json=args.json, plot_dir=None))
    before = machine()
    doc = _report("worker", before, run_worker_bench(opts, progress=_progress))
    print(worker_table(doc))
    _write_json(args.json, doc)
    return 0


# ----------------------------------------------------------------------------- service
def _check_load(args: argparse.Namespace) -> Path:
    """The load options ``bench service`` and ``bench scale`` share; the scenes directory."""
    _positive(args.rate, "--rate", 1000)
    _positive(args.budget, "--budget", 24 * 3600)
    _positive(args.p99_limit, "--p99-limit", 1e6)
    if args.warmup < 0 or args.warmup > 600:
        raise UserError(f"--warmup {args.warmup:g} must be in 0..600 seconds")
    if not (1 <= args.workers <= 64):
        raise UserError(f"--workers {args.workers} must be in 1..64")
    if not (1 <= args.synthetic_boxes <= 10_000):
        raise UserError(f"--synthetic-boxes {args.synthetic_boxes} must be in 1..10000")
    if args.source != "nuscenes":
        return Path()  # synthetic frames: no data read
    args.data = _scenes_data(args.data)
    scenes: Path = args.data / "nuscenes" / "centerpoint_val"
    return scenes


def _scenes_data(given: Path | None) -> Path:
    """The datasets' folder of a run on real nuScenes frames (--source nuscenes), checked to
    hold the val scenes."""
    data = _data(given, "or --source synthetic")
    scenes = data / "nuscenes" / "centerpoint_val"
    if not scenes.is_dir():
        raise UserError(
            f"no nuScenes detections under {scenes}: give --data, or --source synthetic"
        )
    return data


def run_service(args: argparse.Namespace) -> int:
    from simpletrack.bench import plots
    from simpletrack.bench.generators import BenchError
    from simpletrack.bench.report import service_tables
    from simpletrack.bench.service import ServiceBenchOptions, run_service_bench
    from simpletrack.bench.stats import machine

    sensors = _int_list(args.sensors, "--sensors", 1, 1000)  # the service's max_sensors
    _positive(args.seconds, "--seconds", 3600)
    scenes = _check_load(args)
    processes, cpus = _generator(args)
    heartbeat = _heartbeat(args)
    if not (1 <= args.queue_size <= 100_000):
        raise UserError(f"--queue-size {args.queue_size} must be in 1..100000")
    if args.profile_gil and args.profile is None:
        raise UserError("--profile-gil needs --profile DIR")
    if args.server_only and args.against is None:
        raise UserError("--server-only needs --against REF")
    if args.profile is not None and args.against is not None and not args.server_only:
        raise UserError("--profile combines with --against only with --server-only")
    if args.profile is not None:
        import shutil

        if not (shutil.which("py-spy") or (Path(sys.executable).parent / "py-spy").exists()):
            raise UserError("--profile needs py-spy (pip install py-spy)")
    if args.against is not None:
        return _against(
            args,
            "service",
            [
                *("--sensors", args.sensors),
                *("--seconds", repr(args.seconds)),
                *("--warmup", repr(args.warmup)),
                *("--rate", repr(args.rate)),
                *("--workers", str(args.workers)),
                *("--queue-size", str(args.queue_size)),
                *("--source", args.source),
                *_data_option(args.data),
                *("--synthetic-boxes", str(args.synthetic_boxes)),
                *("--p99-limit", repr(args.p99_limit)),
                *("--budget", repr(args.budget)),
                *(("--no-echo",) if args.no_echo else ()),
                *(("--fused",) if args.fused else ()),
                *_generator_option(args),
            ],
        )
    _out_paths(args)
    opts = ServiceBenchOptions(
        sensors=sensors,
        seconds=args.seconds,
        warmup_s=args.warmup,
        rate_hz=args.rate,
        workers=args.workers,
        queue_size=args.queue_size,
        source=args.source,
        data=scenes,
        synthetic_boxes=args.synthetic_boxes,
        budget_s=args.budget,
        echo=not args.no_echo and not args.fused,  # the echo server answers no vehicle key
        profile_dir=args.profile,
        profile_gil=args.profile_gil,
        p99_limit_ms=args.p99_limit,
        fused=args.fused,
        generator_processes=processes,
        generator_cpus=cpus,
        heartbeat_s=heartbeat,
    )
    before = machine()
    try:
        result = run_service_bench(opts, progress=lambda m: print(m, file=sys.stderr, flush=True))
    except BenchError as exc:
        raise UserError(str(exc)) from None
    doc = {
        "benchmark": "service",
        "command": "simpletrack " + " ".join(sys.argv[1:]),
        "clock": "time.monotonic_ns() of the load-generator process (publisher and subscriber)"
        + (
            ", in each of the processes, for the frames of its own sensors" if processes > 1 else ""
        ),
        "options": {
            k: str(v) if isinstance(v, Path) else v
            for k, v in vars(args).items()
            if k not in ("func",)
        },
        "machine_before": before,
        "machine_after": machine(),
        **result,
    }
    print(service_tables(doc))
    if args.plot_dir is not None and result["steps"]:
        steps, plot_dir = result["steps"], args.plot_dir
        written = drawn(
            lambda: [
                plots.service_cdf(steps, plot_dir / "service_latency_cdf.png"),
                plots.service_capacity(steps, plot_dir / "service_capacity.png"),
            ]
        )
        doc["plots"] = [str(p) for p in written]
    _write_json(args.json, doc)
    return 0


# ----------------------------------------------------------------------------- scale
def run_scale(args: argparse.Namespace) -> int:
    from simpletrack.bench import plots
    from simpletrack.bench.generators import BenchError
    from simpletrack.bench.scale import ScaleOptions, scale_tables
    from simpletrack.bench.scale import run_scale as bench
    from simpletrack.bench.service import ServiceBenchOptions
    from simpletrack.bench.stats import machine

    instances = _int_list(args.instances, "--instances", 1, 32)
    # Each member takes up to its max_sensors (1000): a group of several takes more.
    sensors = _int_list(args.sensors, "--sensors", 1, 20_000)
    _positive(args.duration, "--duration", 3600)
    scenes = _check_load(args)
    processes, cpus = _generator(args)
    heartbeat = _heartbeat(args)
    if not (0 <= args.fault_sensors <= 1000):
        raise UserError(f"--fault-sensors {args.fault_sensors} must be in 0..1000 (0: no faults)")
    _out_paths(argparse.Namespace(json=None, plot_dir=args.out))
    bench_opts = ServiceBenchOptions(
        sensors=sensors,
        seconds=args.duration,
        warmup_s=args.warmup,
        rate_hz=args.rate,
        workers=args.workers,
        queue_size=64,
        source=args.source,
        data=scenes,
        synthetic_boxes=args.synthetic_boxes,
        budget_s=args.budget,
        echo=False,
        profile_dir=None,
        p99_limit_ms=args.p99_limit,
        subscribe=args.subscribe,
        generator_processes=processes,
        generator_cpus=cpus,
        heartbeat_s=heartbeat,
        fused=args.fused,
    )
    opts = ScaleOptions(instances, bench_opts, args.fault_sensors)
    before = machine()
    try:
        result = bench(opts, progress=lambda m: print(m, file=sys.stderr, flush=True))
    except BenchError as exc:
        raise UserError(str(exc)) from None
    doc = {
        "benchmark": "scale",
        "command": "simpletrack " + " ".join(sys.argv[1:]),
        "note": "members of one group: each sensor tracked by one member (docs/SCALE.md)",
        "options": {
            k: str(v) if isinstance(v, Path) else v for k, v in vars(args).items() if k != "func"
        }
        | {"p99_limit_ms": args.p99_limit, "rate_hz": args.rate},
        "machine_before": before,
        "machine_after": machine(),
        **result,
    }
    print(scale_tables(doc))
    if args.out is not None:
        out = args.out
        written = drawn(
            lambda: [plots.scale_capacity(result["members"], out / "scale_capacity.png")]
        )
        doc["plots"] = [str(p) for p in written]
        _write_json(out / "scale.json", doc)
    return 0


# ----------------------------------------------------------------------------- fuzz
def run_fuzz(args: argparse.Namespace) -> int:
    if not 1 <= args.frames <= 10_000_000:
        raise UserError(f"--frames {args.frames} must be in 1..10000000")
    if not 1 <= args.sensors <= 1000:
        raise UserError(f"--sensors {args.sensors} must be in 1..1000")
    if not 0.0 <= args.mutated <= 1.0:
        raise UserError(f"--mutated {args.mutated:g} must be in 0..1")
    from simpletrack.bench.fuzz import format_report
    from simpletrack.bench.fuzz import run_fuzz as fuzz

    _out_paths(argparse.Namespace(json=args.json, plot_dir=None))
    report = fuzz(args.frames, args.sensors, args.mutated, args.seed)
    print(format_report(report))
    _write_json(args.json, report.as_dict())
    return 0 if report.clean else 1


# ----------------------------------------------------------------------------- faults
def run_faults(args: argparse.Namespace) -> int:
    from simpletrack.bench.faults import SCENARIOS, as_dicts, format_results
    from simpletrack.bench.faults import run_faults as faults

    names = list(SCENARIOS) if args.scenarios == "all" else args.scenarios.split(",")
    unknown = [n for n in names if n not in SCENARIOS]
    if unknown:
        raise UserError(f"--scenarios: unknown {', '.join(unknown)}; known: {', '.join(SCENARIOS)}")
    _out_paths(argparse.Namespace(json=args.json, plot_dir=None))
    results = faults(names)
    print(format_results(results))
    _write_json(args.json, {"scenarios": as_dicts(results)})
    return 0
