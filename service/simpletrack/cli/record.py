"""``simpletrack record``: write the tracks the service publishes to files, or every message of
chosen sensors to an MCAP recording; fused vehicles' tracks (``<vehicle>/@vehicle/tracks``)
with them when a whole vehicle or the fleet is recorded."""

from __future__ import annotations

import argparse
import queue
import signal
import sys
import threading
import time
from collections.abc import Callable
from pathlib import Path
from types import FrameType
from typing import TYPE_CHECKING, Any, cast

import zenoh

from simpletrack.cli.common import (
    ZENOH_NOTE,
    add_client_args,
    check_prefix,
    client_options,
    open_client_session,
)
from simpletrack.cli.errors import UserError
from simpletrack.client.jsonl import JsonlWriter, message_to_json
from simpletrack.client.publisher import check_name
from simpletrack.client.subscriber import (
    TrackMessage,
    TrackSubscriber,
    VehicleTrackMessage,
    VehicleTrackSubscriber,
)
from simpletrack.mcap.format import LEAVES
from simpletrack.wire import TrackFrame
from simpletrack.wire.keys import TRACKS, VEHICLE_STREAM

if TYPE_CHECKING:
    from simpletrack.datasets.recording import KittiWriter
    from simpletrack.ros2.recording import AutowareMessages

EPILOG = f"""\
formats:
  jsonl   OUT/tracks.jsonl, one line per track frame of any stream (layout in
          clients/README.md); `simpletrack plot` reads it. A fused vehicle's tracks
          (<prefix>/<vehicle>/@vehicle/tracks) come along when the --keys' sensor chunk is
          * (the default does): lines with sensor "@vehicle", "source" (the frame that
          produced it), "sensors" (each fused sensor's condition), and per track its
          "existence" and "updated_ns" (the sensors that updated it, with the stamps).
          --keys 'fleet/veh01/@vehicle/tracks' records those alone.
  kitti   OUT/data_0/<sensor>.txt, KITTI tracking results, one file per stream named by its
          sensor id (what `replay kitti` uses: the sequence, e.g. 0000), boxes converted back
          to the KITTI camera frame, scores as logits. Give --calib (KITTI calib folder) for
          the 2D boxes that `simpletrack eval kitti --results OUT/data_0` needs.
  mcap    OUT is a file: every message on the --sensors' detections, tracks and errors
          keys (--what), payload bytes unchanged (message encoding msgpack, JSON Schema of
          each message), one channel per key; log time = receive time, publish time = the
          frame's stamp. A whole vehicle (veh01/*) or the fleet (*/*, the default) brings
          its fused vehicles' tracks, <prefix>/<vehicle>/@vehicle/tracks (VehicleTrackFrame),
          when --what has tracks; veh01/@vehicle records those alone. For Foxglove (which
          decodes no msgpack), each key also gets <key>/json (the message as JSON, its
          boxes or tracks one object of numbers each, for the Plot panel:
          fleet/veh01/lidar/tracks/json.tracks[:]{{id==7}}.x) and detections and tracks
          <key>/scene (foxglove.SceneUpdate boxes for the 3D panel; fused tracks
          labelled with their existence), and detections with a
          pose or an extrinsic <key>/tf (foxglove.FrameTransform); --no-foxglove writes only
          the raw channels. `simpletrack replay mcap OUT` publishes its detections again
          (fused sensors' too; the fused tracks are the service's to make);
          `mcap info OUT` and Foxglove open it. --frames counts raw messages here.
          --ros2 [BAG] also writes BAG (default OUT with .ros2.mcap), a ROS 2 bag (MCAP,
          profile ros2, cdr) of the same frames as autoware_perception_msgs:
          /simpletrack/<vehicle>/<sensor>/detected_objects (DetectedObjects),
          /simpletrack/<vehicle>/<sensor>/tracked_objects and, fused,
          /simpletrack/<vehicle>/tracked_objects (TrackedObjects), converted as
          `simpletrack bridge ros2` does (docs/ROS2.md, "Recordings"); labels from each
          message's preset (nuscenes, kitti, wod, by its classes) or --ros2-labels.

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

  # a field recording of one vehicle: what it sent, what came back (its fused tracks
  # too), until Ctrl-C
  simpletrack record --format mcap --out out/veh01.mcap --sensors 'veh01/*'

  # the same with a ROS 2 bag of Autoware messages beside it (out/veh01.ros2.mcap)
  simpletrack record --format mcap --out out/veh01.mcap --sensors 'veh01/*' --ros2

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
        help="key expression of the track frames (default: <prefix>/*/*/tracks, the whole "
        "fleet); a * sensor chunk brings the fused <vehicle>/@vehicle/tracks too",
    )
    p.add_argument("--out", type=Path, required=True, help="output folder (mcap: output file)")
    p.add_argument(
        "--format", choices=("jsonl", "kitti", "mcap"), default="jsonl", help="default jsonl"
    )
    p.add_argument(
        "--sensors",
        nargs="+",
        metavar="VEHICLE/SENSOR",
        help="mcap: the streams to record, * allowed (default */*: the whole fleet); "
        "VEHICLE/* brings its fused tracks (VEHICLE/@vehicle: those alone)",
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
    p.add_argument(
        "--ros2",
        nargs="?",
        const=True,
        type=Path,
        metavar="BAG",
        help="mcap: also a ROS 2 bag of Autoware DetectedObjects/TrackedObjects (default: OUT "
        "with .ros2.mcap)",
    )
    p.add_argument(
        "--ros2-labels",
        metavar="SPEC",
        help="mcap --ros2: label map, a preset (nuscenes, kitti, wod) or LABEL=class pairs "
        "(default: each message's preset, by its classes)",
    )
    p.add_argument("--frames", type=int, help="stop after this many frames")
    p.add_argument("--duration", type=float, help="stop after this many seconds")
    p.add_argument("--idle", type=float, help="stop after this many seconds without frames")
    p.add_argument("--calib", type=Path, help="KITTI calib folder (<sensor>.txt) for 2D boxes")
    p.add_argument("--quiet", action="store_true", help="no progress line on stderr")
    add_client_args(p)
    p.set_defaults(func=run)


def _check(args: argparse.Namespace) -> tuple[str | None, str | None]:
    """(sensors' tracks, fused vehicles' tracks) key expressions for jsonl and kitti."""
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
    elif args.ros2 is not None or args.ros2_labels is not None:
        raise UserError("--ros2 and --ros2-labels apply to --format mcap only")
    keys = args.keys or f"{prefix}/*/*/tracks"
    try:
        zenoh.KeyExpr(keys)
    except (zenoh.ZError, ValueError) as exc:
        raise UserError(f"--keys {keys!r} is not a valid key expression: {exc}") from None
    sensors, fused = track_keys(keys)
    if args.format == "kitti":
        if sensors is None:
            raise UserError(
                f"--keys {keys!r}: KITTI results are a sensor's; record a vehicle's fused "
                "tracks as jsonl or mcap"
            )
        fused = None
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
    return sensors, fused


def track_keys(keys: str) -> tuple[str | None, str | None]:
    """(sensors' tracks, fused vehicles' tracks) key expressions ``keys`` stands for. A ``*``
    never matches the verbatim ``@vehicle`` chunk, so ``<prefix>/<vehicle>/*/tracks`` (a
    vehicle's, or with ``*`` every vehicle's, sensors) also means
    ``<prefix>/<vehicle>/@vehicle/tracks``; ``.../@vehicle/tracks`` means that alone."""
    chunks = keys.split("/")
    if len(chunks) < 4 or chunks[-1] != TRACKS:
        return keys, None
    if chunks[-2] == VEHICLE_STREAM:
        return None, keys
    if chunks[-2] == "*":
        return keys, "/".join([*chunks[:-2], VEHICLE_STREAM, TRACKS])
    return keys, None


def vehicle_message_to_json(msg: VehicleTrackMessage) -> dict[str, Any]:
    """A fused vehicle's tracks as a JSON lines object: a track frame's line (sensor
    ``@vehicle``) with ``source`` (the sensor and seq of the frame that produced it),
    ``sensors`` (each fused sensor's condition), and per track its ``existence`` and
    ``updated_ns`` (each sensor that updated it: the stamp of its last update)."""
    f = msg.frame
    # message_to_json reads only header fields a VehicleTrackFrame shares with a TrackFrame.
    obj = message_to_json(cast(TrackFrame, f), msg.tracks)
    obj["sensor"] = VEHICLE_STREAM
    obj["source"] = {"sensor": f.sensor, "seq": f.sensor_seq}
    obj["sensors"] = {s: c.value for s, c in msg.sensor_state.items()}
    existence = msg.existence.tolist()
    for i, track in enumerate(obj["tracks"]):
        track["existence"] = round(existence[i], 4)
        track["updated_ns"] = msg.contributors(i)
    return obj


def _vehicle_subscriber(
    session: zenoh.Session, expr: str, callback: Callable[[VehicleTrackMessage], None]
) -> VehicleTrackSubscriber:
    """A fused tracks subscriber for ``<head>/<vehicle>/@vehicle/tracks``; a vehicle chunk
    that is a pattern (``veh0*``) subscribes to every vehicle, filtered in ``callback``."""
    chunks = expr.split("/")
    vehicle = chunks[-3]
    try:
        check_name("vehicle", vehicle)
    except ValueError:
        vehicle = "*"
    want = zenoh.KeyExpr(expr)

    def on_message(msg: VehicleTrackMessage) -> None:
        if want.includes(zenoh.KeyExpr(msg.key)):
            callback(msg)

    return VehicleTrackSubscriber(
        session, prefix="/".join(chunks[:-3]), vehicle=vehicle, callback=on_message
    )


def run(args: argparse.Namespace) -> int:
    sensor_keys, vehicle_keys = _check(args)
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
    kitti: KittiWriter | None = None
    if args.format == "kitti":  # the KITTI layout and calibration: the service extra's datasets
        from simpletrack.datasets.recording import KittiWriter

        kitti = KittiWriter(args.out, args.calib)
    frames = 0
    streams: set[tuple[str, str]] = set()
    started = time.monotonic()
    last = None
    reason = "interrupted"
    received: queue.Queue[TrackMessage | VehicleTrackMessage] = queue.Queue()
    try:
        subs: list[TrackSubscriber | VehicleTrackSubscriber] = []
        if sensor_keys is not None:
            subs.append(TrackSubscriber(session, key_expr=sensor_keys, callback=received.put))
        if vehicle_keys is not None:
            subs.append(_vehicle_subscriber(session, vehicle_keys, received.put))
        if not args.quiet:
            keys = " and ".join(k for k in (sensor_keys, vehicle_keys) if k is not None)
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
            try:
                msg = received.get(timeout=0.2)
            except queue.Empty:
                continue
            last = time.monotonic()
            if isinstance(msg, VehicleTrackMessage):
                if jsonl is not None:
                    jsonl.write(vehicle_message_to_json(msg))
            else:
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
        invalid = sum(sub.invalid for sub in subs)
        for sub in subs:
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
    from simpletrack.mcap.format import recorded_keys
    from simpletrack.mcap.ros2 import Ros2Bag
    from simpletrack.mcap.writer import McapRecorder, subscribe

    sensors = parse_sensors(args.sensors)
    what = parse_what(args.what, LEAVES)
    if not recorded_keys(args.prefix, sensors, what):
        raise UserError(
            f"--sensors {' '.join(args.sensors)}: a fused vehicle's stream has tracks only; "
            "--what has no tracks"
        )
    options = client_options(args)
    if not args.out.parent.is_dir():
        raise UserError(f"--out {args.out}: no folder {args.out.parent}")
    bag_path, messages = _ros2_options(args)
    stop = threading.Event()

    def on_signal(signum: int, _frame: FrameType | None) -> None:
        stop.set()

    previous = {s: signal.signal(s, on_signal) for s in (signal.SIGINT, signal.SIGTERM)}
    started = time.monotonic()
    reason = "interrupted"
    recorder = None
    bag = None
    try:
        session = open_client_session(options)
        try:
            if bag_path is not None and messages is not None:
                try:
                    bag = Ros2Bag(bag_path, args.prefix, messages)
                except OSError as exc:
                    raise UserError(f"--ros2 {bag_path}: {exc.strerror}") from None
            try:
                recorder = McapRecorder(
                    args.out, args.prefix, foxglove=not args.no_foxglove, ros2=bag
                )
            except OSError as exc:
                raise UserError(f"--out {args.out}: {exc.strerror}") from None
            subs = subscribe(session, args.prefix, sensors, what, recorder)
            if not args.quiet:
                keys = " ".join(recorded_keys(args.prefix, sensors, what))
                print(
                    f"recording {keys} to {args.out} (mcap); Ctrl-C to stop",
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
            recorder.close()  # and the bag
        elif bag is not None:
            bag.close()
        for s, handler in previous.items():
            signal.signal(s, handler)
    written = recorder.messages if recorder is not None else 0
    unrecorded = recorder.unrecorded if recorder is not None else 0
    ros2 = ""
    if bag is not None:
        ros2 = f"; {bag.messages} ROS 2 messages to {bag.path}" + (
            f" ({bag.skipped} frames the wire's checks refused left out)" if bag.skipped else ""
        )
    print(
        f"record: {reason}: {written} messages in {time.monotonic() - started:.1f} s to {args.out}"
        + ros2
        + (f"; {unrecorded} not recorded (the writer fell behind)" if unrecorded else "")
    )
    return 0


def _ros2_options(args: argparse.Namespace) -> tuple[Path | None, AutowareMessages | None]:
    """The bag's path and its messages for ``--ros2`` (None, None without it)."""
    from simpletrack.mcap.ros2 import default_path
    from simpletrack.ros2.recording import AutowareMessages

    if args.ros2 is None:
        if args.ros2_labels is not None:
            raise UserError("--ros2-labels applies with --ros2")
        return None, None
    path = default_path(args.out) if args.ros2 is True else args.ros2
    if path.resolve() == args.out.resolve():
        raise UserError(f"--ros2 {path}: the recording's own file (--out)")
    if path.is_dir() or not path.parent.is_dir():
        raise UserError(f"--ros2 {path}: not a file in an existing folder")
    try:
        return path, AutowareMessages(args.ros2_labels)
    except ValueError as exc:
        raise UserError(str(exc)) from None


def _idle(last_ns: int, idle_s: float) -> bool:
    return time.time_ns() - last_ns >= idle_s * 1e9
