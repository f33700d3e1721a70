"""``simpletrack record``: write the tracks the service publishes to files, or every message of
chosen sensors to an MCAP recording."""

from __future__ import annotations

import argparse
import signal
import sys
import threading
import time
from pathlib import Path
from types import FrameType

import zenoh

from simpletrack.cli.common import (
    ZENOH_NOTE,
    add_client_args,
    check_prefix,
    client_options,
    open_client_session,
)
from simpletrack.cli.errors import UserError
from simpletrack.client.subscriber import TrackSubscriber
from simpletrack.datasets.recording import JsonlWriter, KittiWriter, message_to_json
from simpletrack.mcap.format import LEAVES

EPILOG = f"""\
formats:
  jsonl   OUT/tracks.jsonl, one line per track frame of any stream (layout in
          clients/README.md); `simpletrack plot` reads it.
  kitti   OUT/data_0/<sensor>.txt, KITTI tracking results, one file per stream named by its
          sensor id (what `replay kitti` uses: the sequence, e.g. 0000), boxes converted back
          to the KITTI camera frame, scores as logits. Give --calib (KITTI calib folder) for
          the 2D boxes that `simpletrack eval kitti --results OUT/data_0` needs.
  mcap    OUT is a file: every message on the --sensors' detections, tracks and errors
          keys (--what), payload bytes unchanged (message encoding msgpack, JSON Schema of
          each message), one channel per key; log time = receive time, publish time = the
          frame's stamp. For Foxglove (which decodes no msgpack), each key also gets
          <key>/json (the message as JSON, bins base64) and detections and tracks
          <key>/scene (foxglove.SceneUpdate boxes for the 3D panel), and detections with a
          pose <key>/tf (foxglove.FrameTransform); --no-foxglove writes only the raw
          channels. `simpletrack replay mcap OUT` publishes its detections again;
          `mcap info OUT` and Foxglove open it. --frames counts raw messages here.

Stops on Ctrl-C or SIGTERM (exit 0, files complete), after --frames N frames, after
--duration S seconds, or after --idle S seconds without frames once some arrived.

{ZENOH_NOTE}

examples:
  # everything the fleet's planners would receive, as JSON lines, until Ctrl-C
  simpletrack record --out out/rec

  # a KITTI replay, ready for the evaluator
  simpletrack record --keys 'fleet/kitti/*/tracks' --format kitti \\
      --calib ../shared/data/kitti/calib --out out/kitti-zenoh --idle 5
  simpletrack eval kitti --results out/kitti-zenoh/data_0 --seqs 0000

  # a field recording of one vehicle: what it sent, what came back, until Ctrl-C
  simpletrack record --format mcap --out out/veh01.mcap --sensors 'veh01/*'

  # one vehicle's lidar, 500 frames
  simpletrack record --keys 'fleet/veh01/lidar/tracks' --frames 500 --out out/veh01
"""


def register(subparsers: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    p = subparsers.add_parser(
        "record",
        help="record published tracks to files (KITTI results or JSON lines), or messages to MCAP",
        description="Subscribe to track frames by key expression and write them to files.",
        formatter_class=argparse.RawDescriptionHelpFormatter,
        epilog=EPILOG,
    )
    p.add_argument(
        "--keys",
        help="key expression of the track frames (default: <prefix>/*/*/tracks, the whole fleet)",
    )
    p.add_argument("--out", type=Path, required=True, help="output folder (mcap: output file)")
    p.add_argument(
        "--format", choices=("jsonl", "kitti", "mcap"), default="jsonl", help="default jsonl"
    )
    p.add_argument(
        "--sensors",
        nargs="+",
        metavar="VEHICLE/SENSOR",
        help="mcap: the streams to record, * allowed (default */*: the whole fleet)",
    )
    p.add_argument(
        "--what",
        default=",".join(LEAVES),
        help=f"mcap: comma-separated keys of each sensor to record (default {','.join(LEAVES)})",
    )
    p.add_argument(
        "--no-foxglove",
        action="store_true",
        help="mcap: only the raw msgpack channels, not their JSON, scene and transform twins",
    )
    p.add_argument("--frames", type=int, help="stop after this many frames")
    p.add_argument("--duration", type=float, help="stop after this many seconds")
    p.add_argument("--idle", type=float, help="stop after this many seconds without frames")
    p.add_argument("--calib", type=Path, help="KITTI calib folder (<sensor>.txt) for 2D boxes")
    p.add_argument("--quiet", action="store_true", help="no progress line on stderr")
    add_client_args(p)
    p.set_defaults(func=run)


def _check(args: argparse.Namespace) -> str:
    prefix = check_prefix(args.prefix)
    if args.format == "mcap":
        if args.keys is not None:
            raise UserError("--keys applies to jsonl and kitti; mcap records --sensors")
        if args.out.is_dir():
            raise UserError(f"--out {args.out} is a folder; mcap writes a file")
    elif args.sensors is not None or args.what != ",".join(LEAVES):
        raise UserError("--sensors and --what apply to --format mcap only")
    elif args.no_foxglove:
        raise UserError("--no-foxglove applies to --format mcap only")
    keys = args.keys or f"{prefix}/*/*/tracks"
    try:
        zenoh.KeyExpr(keys)
    except (zenoh.ZError, ValueError) as exc:
        raise UserError(f"--keys {keys!r} is not a valid key expression: {exc}") from None
    for flag in ("frames", "duration", "idle"):
        value = getattr(args, flag)
        if value is not None and value <= 0:
            raise UserError(f"--{flag} {value} must be positive")
    if args.calib is not None:
        if args.format != "kitti":
            raise UserError("--calib applies to --format kitti only")
        if not args.calib.is_dir():
            raise UserError(f"--calib {args.calib}: no such folder")
    if args.format != "mcap" and args.out.exists() and not args.out.is_dir():
        raise UserError(f"--out {args.out} exists and is not a folder")
    return keys


def run(args: argparse.Namespace) -> int:
    keys = _check(args)
    if args.format == "mcap":
        return run_mcap(args)
    options = client_options(args)
    args.out.mkdir(parents=True, exist_ok=True)
    stop = threading.Event()

    def on_signal(signum: int, _frame: FrameType | None) -> None:
        stop.set()

    previous = {s: signal.signal(s, on_signal) for s in (signal.SIGINT, signal.SIGTERM)}
    session = open_client_session(options)
    jsonl = JsonlWriter(args.out / "tracks.jsonl") if args.format == "jsonl" else None
    kitti = KittiWriter(args.out, args.calib) if args.format == "kitti" else None
    frames = 0
    streams: set[tuple[str, str]] = set()
    started = time.monotonic()
    last = None
    reason = "interrupted"
    try:
        sub = TrackSubscriber(session, key_expr=keys)
        if not args.quiet:
            print(
                f"recording {keys} to {args.out} ({args.format}); Ctrl-C to stop",
                file=sys.stderr,
                flush=True,
            )
        while not stop.is_set():
            now = time.monotonic()
            if args.duration is not None and now - started >= args.duration:
                reason = "duration reached"
                break
            if args.idle is not None and last is not None and now - last >= args.idle:
                reason = f"idle for {args.idle:g} s"
                break
            msg = sub.recv(timeout=0.2)
            if msg is None:
                continue
            last = time.monotonic()
            if jsonl is not None:
                jsonl.write(message_to_json(msg.frame, msg.tracks))
            if kitti is not None:
                try:
                    kitti.write(msg.frame, msg.tracks)
                except FileNotFoundError as exc:
                    raise UserError(str(exc)) from None
            frames += 1
            streams.add((msg.vehicle, msg.sensor))
            if args.frames is not None and frames >= args.frames:
                reason = f"{frames} frames"
                break
        invalid = sub.invalid
        sub.close()
    finally:
        session.close()  # type: ignore[no-untyped-call]
        paths = kitti.close() if kitti is not None else []
        if jsonl is not None:
            jsonl.close()
            paths = [jsonl.path]
        for s, handler in previous.items():
            signal.signal(s, handler)
    where = ", ".join(str(p) for p in paths[:4]) + (", ..." if len(paths) > 4 else "")
    print(
        f"record: {reason}: {frames} frames from {len(streams)} stream(s) in "
        f"{time.monotonic() - started:.1f} s to {where or args.out}"
        + (f"; {invalid} undecodable frames skipped" if invalid else "")
    )
    return 0


def run_mcap(args: argparse.Namespace) -> int:
    from simpletrack.cli.record_mcap import parse_sensors, parse_what
    from simpletrack.mcap.writer import McapRecorder, subscribe

    sensors = parse_sensors(args.sensors)
    what = parse_what(args.what, LEAVES)
    options = client_options(args)
    if not args.out.parent.is_dir():
        raise UserError(f"--out {args.out}: no folder {args.out.parent}")
    stop = threading.Event()

    def on_signal(signum: int, _frame: FrameType | None) -> None:
        stop.set()

    previous = {s: signal.signal(s, on_signal) for s in (signal.SIGINT, signal.SIGTERM)}
    started = time.monotonic()
    reason = "interrupted"
    recorder = None
    try:
        session = open_client_session(options)
        try:
            try:
                recorder = McapRecorder(args.out, args.prefix, foxglove=not args.no_foxglove)
            except OSError as exc:
                raise UserError(f"--out {args.out}: {exc.strerror}") from None
            subs = subscribe(session, args.prefix, sensors, what, recorder)
            if not args.quiet:
                streams = " ".join(f"{v}/{s}" for v, s in sensors)
                print(
                    f"recording {','.join(what)} of {streams} under {args.prefix} to {args.out} "
                    "(mcap); Ctrl-C to stop",
                    file=sys.stderr,
                    flush=True,
                )
            while not stop.wait(0.1):
                if args.duration is not None and time.monotonic() - started >= args.duration:
                    reason = "duration reached"
                    break
                last = recorder.last_ns
                if args.idle is not None and last is not None and _idle(last, args.idle):
                    reason = f"idle for {args.idle:g} s"
                    break
                if args.frames is not None and recorder.messages >= args.frames:
                    reason = f"{recorder.messages} messages"
                    break
            for sub in subs:
                sub.undeclare()  # type: ignore[no-untyped-call]
        finally:
            session.close()  # type: ignore[no-untyped-call]
    finally:
        if recorder is not None:
            recorder.close()
        for s, handler in previous.items():
            signal.signal(s, handler)
    messages = recorder.messages if recorder is not None else 0
    unrecorded = recorder.unrecorded if recorder is not None else 0
    print(
        f"record: {reason}: {messages} messages in {time.monotonic() - started:.1f} s to {args.out}"
        + (f"; {unrecorded} not recorded (the writer fell behind)" if unrecorded else "")
    )
    return 0


def _idle(last_ns: int, idle_s: float) -> bool:
    return time.time_ns() - last_ns >= idle_s * 1e9
