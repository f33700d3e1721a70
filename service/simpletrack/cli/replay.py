"""``simpletrack replay kitti|nuscenes|mcap``: publish recorded detection files onto Zenoh, paced
at the data's frame rate (or a chosen one, or as fast as the service keeps up)."""

from __future__ import annotations

import argparse
import sys
import threading
import time
from collections import Counter
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

from simpletrack.cli.common import (
    ZENOH_NOTE,
    add_client_args,
    check_prefix,
    client_options,
    open_client_session,
)
from simpletrack.cli.errors import UserError
from simpletrack.client.publisher import DetectionPublisher, check_name
from simpletrack.client.subscriber import TrackMessage, TrackSubscriber
from simpletrack.session import Congestion
from simpletrack.wire import FrameError

if TYPE_CHECKING:  # replay kitti|nuscenes need the service extra; replay mcap runs light
    from simpletrack.core.boxes import Boxes

EPILOG = f"""\
Each sequence (KITTI) or scene (nuScenes) is its own sensor stream, named by --sensor
(default: the sequence name, e.g. fleet/kitti/0000/detections), with seq = frame index and
stamp_ns = start time + the frame's time in the data (10 Hz KITTI, 2 Hz nuScenes). Frames
without detections are sent too, so the tracker ages its tracks exactly as offline.

mcap: `replay mcap FILE.mcap` publishes the detections channels of a `simpletrack record
--format mcap` recording, payload bytes as recorded (vehicle, sensor, seq and stamps
included; a fused sensor's extrinsic or pose too), on their recorded keys, or under another
--prefix. --sensors picks streams. A fused vehicle's recorded tracks
(<vehicle>/@vehicle/tracks) are not sent: a service that fuses the vehicle makes them again
from the detections, and a fused sensor's frame counts as answered once the vehicle's tracks
reach its stamp.
--rate recorded (the default) keeps the recorded pace (receive time differences); a number is
each stream's frames per second.

Pacing: --rate 10 sends 10 frames per second; --rate max sends as fast as the service keeps
up: at most --window frames are in flight (sent, but neither tracked nor refused yet).

Exit code: 0 when every frame was tracked; 1 when some were refused or never answered;
2 on bad arguments, missing files or no service.

{ZENOH_NOTE}

examples:
  # one KITTI train sequence at its real rate to a local `simpletrack serve --preset kitti`
  simpletrack replay kitti --data ../shared/data/kitti --seqs 0000

  # three sequences as fast as possible, on vehicle "car1", sensors named cam-0000, ...
  simpletrack replay kitti --data ../shared/data/kitti --seqs 0000,0002,0003 \\
      --vehicle car1 --sensor 'cam-{{seq}}' --rate max

  # a field recording's detections into a fresh service, under another prefix, at full speed
  simpletrack replay mcap out/veh01.mcap --prefix lab --rate max

  # nuScenes CenterPoint scenes to a service started with --preset nuscenes
  simpletrack replay nuscenes --data ../shared/data/nuscenes/centerpoint_val \\
      --seqs scene-0003,scene-0012 --rate max --connect tcp/10.0.0.5:7447
"""


def register(subparsers: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    p = subparsers.add_parser(
        "replay",
        help="publish KITTI, nuScenes or MCAP-recorded detections onto Zenoh at their rate",
        description="Replay recorded detection files to the tracking service over Zenoh, "
        "with a progress bar and a summary of frames sent, tracked and refused.",
        formatter_class=argparse.RawDescriptionHelpFormatter,
        epilog=EPILOG,
    )
    p.add_argument(
        "dataset", choices=("kitti", "nuscenes", "mcap"), help="layout of the detection files"
    )
    p.add_argument("file", nargs="?", type=Path, help="mcap: the recording (FILE.mcap)")
    p.add_argument(
        "--data",
        type=Path,
        help="KITTI folder (detections/pointrcnn/...) or nuScenes folder of scene-*.txt files",
    )
    p.add_argument(
        "--sensors",
        nargs="+",
        metavar="VEHICLE/SENSOR",
        help="mcap: the recorded streams to send (default: all)",
    )
    p.add_argument("--seqs", help="comma-separated sequences or scenes (default: all found)")
    p.add_argument(
        "--classes",
        help="comma-separated classes to send (default: KITTI Car,Pedestrian,Cyclist; "
        "nuScenes the 7 tracked classes)",
    )
    p.add_argument("--vehicle", help="vehicle id in the keys (default: the dataset name)")
    p.add_argument(
        "--sensor", default="{seq}", help="sensor id; {seq} becomes the sequence (default {seq})"
    )
    p.add_argument(
        "--rate",
        default=None,
        help="frames per second, or 'max' (default: the data's rate, 10 KITTI / 2 nuScenes); "
        "mcap also 'recorded' (its default)",
    )
    p.add_argument("--window", type=int, default=32, help="frames in flight at most (default 32)")
    p.add_argument(
        "--congestion",
        choices=[c.value for c in Congestion],
        default=Congestion.BLOCK.value,
        help="Zenoh congestion control of the publishers (default block: lossless)",
    )
    p.add_argument(
        "--wait", type=float, default=10.0, help="seconds to wait for a service (default 10)"
    )
    p.add_argument(
        "--answer-timeout",
        type=float,
        default=10.0,
        help="give up when the service answers nothing for this long (default 10 s)",
    )
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    add_client_args(p, prefix=False)
    p.add_argument(
        "--prefix",
        help="first key chunk(s) of the service (default fleet; mcap: the recorded keys')",
    )
    p.set_defaults(func=run)


@dataclass(frozen=True, slots=True)
class ReplayFrame:
    index: int
    stamp: float  # seconds from the start of the sequence
    boxes: Boxes


@dataclass
class Sequence_:
    name: str
    frames: list[ReplayFrame]
    classes: tuple[str, ...]
    period: float


def load_kitti(
    data: Path, seqs: list[str] | None, classes: list[str] | None
) -> Iterator[Sequence_]:
    from simpletrack.core.config import preset
    from simpletrack.datasets.kitti import FRAME_PERIOD, KITTI_CLASSES, load_sequence

    config = preset("kitti")
    wanted = classes or list(KITTI_CLASSES)
    for c in wanted:
        if c not in KITTI_CLASSES:
            raise UserError(f"unknown KITTI class {c!r}; choose from {', '.join(KITTI_CLASSES)}")
    det_dir = data / "detections" / "pointrcnn"
    if not det_dir.is_dir():
        raise UserError(f"--data {data}: no detections/pointrcnn folder (KITTI layout expected)")
    names = seqs or sorted({p.stem for c in wanted for p in (det_dir / c).glob("*.txt")})
    if not names:
        raise UserError(f"--data {data}: no sequences found")
    for name in names:
        try:
            frames = load_sequence(data, name, config, wanted)
        except (FileNotFoundError, ValueError) as exc:
            raise UserError(str(exc)) from None
        yield Sequence_(
            name,
            [ReplayFrame(f.index, f.stamp, f.boxes) for f in frames],
            config.class_names,
            FRAME_PERIOD,
        )


def load_nuscenes(
    data: Path, seqs: list[str] | None, classes: list[str] | None
) -> Iterator[Sequence_]:
    from simpletrack.core.config import preset
    from simpletrack.datasets.nuscenes import FRAME_PERIOD_S, TYPE_NAMES, read_scene, scene_files

    wanted = classes or list(preset("nuscenes").class_names)
    for c in wanted:
        if c not in TYPE_NAMES.values():
            raise UserError(
                f"unknown nuScenes class {c!r}; choose from {', '.join(TYPE_NAMES.values())}"
            )
    if not data.is_dir():
        raise UserError(f"--data {data}: no such folder")
    try:
        paths = list(scene_files(data, seqs))
    except FileNotFoundError as exc:
        raise UserError(str(exc)) from None
    if not paths:
        raise UserError(f"--data {data}: no scene-*.txt files")
    for path in paths:
        try:
            frames = read_scene(path, wanted)
        except ValueError as exc:
            raise UserError(f"{path}: {exc}") from None
        yield Sequence_(
            path.stem,
            [ReplayFrame(f.index, f.stamp, f.boxes) for f in frames],
            tuple(wanted),
            FRAME_PERIOD_S,
        )


@dataclass
class Answers:
    """What came back from the service, per (sensor, seq): a track frame or an error."""

    cond: threading.Condition = field(default_factory=threading.Condition)
    answered: set[tuple[str, str, int]] = field(default_factory=set)
    tracked: int = 0
    errors: Counter[str] = field(default_factory=Counter)
    last_answer: float = field(default_factory=time.monotonic)
    fused: int = 0  # of ``tracked``: answered by a fused vehicle's tracks

    def on_fused(self, keys: list[tuple[str, str, int]]) -> None:
        """Frames of fused sensors a vehicle's tracks message answered (replay_mcap.py)."""
        with self.cond:
            for key in keys:
                if key not in self.answered:
                    self.answered.add(key)
                    self.tracked += 1
                    self.fused += 1
            self.last_answer = time.monotonic()
            self.cond.notify_all()

    def on_tracks(self, msg: TrackMessage) -> None:
        with self.cond:
            key = (msg.vehicle, msg.sensor, msg.seq)
            if key not in self.answered:
                self.answered.add(key)
                self.tracked += 1
            self.last_answer = time.monotonic()
            self.cond.notify_all()

    def on_error(self, err: FrameError) -> None:
        with self.cond:
            self.errors[err.reason.value] += 1
            if err.seq is not None:
                self.answered.add((err.vehicle, err.sensor, err.seq))
            self.last_answer = time.monotonic()
            self.cond.notify_all()

    def count(self) -> int:
        with self.cond:
            return len(self.answered)

    def wait_below(self, sent: int, window: int, timeout: float) -> bool:
        """Wait until fewer than ``window`` frames are unanswered; False if the service went
        quiet for ``timeout`` seconds."""
        with self.cond:
            while sent - len(self.answered) >= window:
                quiet = time.monotonic() - self.last_answer
                if quiet >= timeout:
                    return False
                self.cond.wait(min(0.5, timeout - quiet))
            return True


def parse_rate(text: str | None, default: float) -> float | None:
    """Frames per second, or None for 'max'."""
    if text is None:
        return default
    if text.strip().lower() == "max":
        return None
    try:
        rate = float(text)
    except ValueError:
        rate = -1.0
    if not 0 < rate <= 10_000:
        raise UserError(f"--rate {text!r} must be a positive number of frames per second or 'max'")
    return rate


def run(args: argparse.Namespace) -> int:
    if args.dataset == "mcap":
        from simpletrack.cli.replay_mcap import run_mcap

        return run_mcap(args)
    if args.file is not None:
        raise UserError(f"{args.file}: replay {args.dataset} reads --data, not a file argument")
    if args.sensors is not None:
        raise UserError("--sensors applies to replay mcap only")
    if args.data is None:
        raise UserError(f"replay {args.dataset} needs --data")
    prefix = check_prefix(args.prefix or "fleet")
    seqs = [s.strip() for s in args.seqs.split(",") if s.strip()] if args.seqs else None
    classes = [c.strip() for c in args.classes.split(",") if c.strip()] if args.classes else None
    vehicle = args.vehicle or args.dataset
    if args.window < 1:
        raise UserError(f"--window {args.window} must be at least 1")
    if seqs is not None and len(seqs) > 1 and "{seq}" not in args.sensor:
        raise UserError("several sequences need a --sensor containing {seq} (one stream each)")
    try:
        check_name("vehicle", vehicle)
        check_name("sensor", args.sensor.replace("{seq}", "0000"))
    except ValueError as exc:
        raise UserError(str(exc)) from None
    if not args.data.exists():
        raise UserError(f"--data {args.data}: no such folder")
    loader = load_kitti if args.dataset == "kitti" else load_nuscenes
    sequences = list(loader(args.data, seqs, classes))  # read everything first: fail early
    default_rate = 1.0 / sequences[0].period
    rate = parse_rate(args.rate, default_rate)
    options = client_options(args)
    total = sum(len(s.frames) for s in sequences)

    session = open_client_session(options)
    answers = Answers()
    publishers: list[DetectionPublisher] = []
    sent = 0
    started = time.monotonic()
    outcome = "done"
    try:
        subscriber = TrackSubscriber(
            session, prefix=prefix, vehicle=vehicle, callback=answers.on_tracks
        )
        with _progress(total, args.no_progress) as advance:
            for seq in sequences:
                sensor = args.sensor.replace("{seq}", seq.name)
                try:
                    pub = DetectionPublisher(
                        session,
                        vehicle,
                        sensor,
                        classes=seq.classes,
                        prefix=prefix,
                        congestion=Congestion(args.congestion),
                        on_error=answers.on_error,
                    )
                except ValueError as exc:
                    raise UserError(str(exc)) from None
                publishers.append(pub)  # kept open: refusals of late frames still arrive
                if sent == 0 and not pub.wait_for_service(args.wait):
                    raise UserError(
                        f"no service subscribed to {pub.keys.detections(vehicle, sensor)} after "
                        f"{args.wait:g} s (is `simpletrack serve` running? check --connect)"
                    )
                # Stamps are the data's times from this sequence's start (the tracker's dt),
                # anchored at the wall clock so that latencies read sensibly at the real rate.
                base_ns = time.time_ns()
                seq_start = time.monotonic()
                for f in seq.frames:
                    if rate is not None:
                        delay = seq_start + f.index / rate - time.monotonic()
                        if delay > 0:
                            time.sleep(delay)
                    if not answers.wait_below(sent, args.window, args.answer_timeout):
                        outcome = "service stopped answering"
                        break
                    pub.publish(f.boxes, stamp_ns=base_ns + round(f.stamp * 1e9), seq=f.index)
                    sent += 1
                    advance(1)
                if outcome != "done":
                    break
        deadline = time.monotonic() + args.answer_timeout
        with answers.cond:
            while len(answers.answered) < sent and time.monotonic() < deadline:
                answers.cond.wait(0.2)
        subscriber.close()
        for pub in publishers:
            pub.close()
    except KeyboardInterrupt:
        outcome = "interrupted"
    finally:
        session.close()  # type: ignore[no-untyped-call]

    elapsed = time.monotonic() - started
    answered = answers.count()
    errors = sum(answers.errors.values())
    print(
        f"replay {args.dataset}: {outcome}: {len(sequences)} sequence(s), {sent}/{total} frames "
        f"sent in {elapsed:.1f} s ({sent / max(elapsed, 1e-9):.1f} frames/s), "
        f"{answers.tracked} tracked, {errors} refused, {max(sent - answered, 0)} unanswered"
    )
    for reason, n in sorted(answers.errors.items()):
        print(f"  refused {n} x {reason}")
    if answers.errors.keys() & {"seq_not_increasing", "out_of_order", "duplicate_seq"}:
        print(
            "  hint: the service still holds these streams (an earlier replay?): "
            "give another --vehicle, or restart the service"
        )
    sys.stdout.flush()
    if outcome == "interrupted":
        return 130
    return 0 if (outcome == "done" and errors == 0 and answered >= sent == total) else 1


class _progress:
    """A rich progress bar on stderr when it is a terminal; nothing otherwise (nor on the
    light install, which has no rich)."""

    def __init__(self, total: int, disabled: bool) -> None:
        self.progress: Any = None
        try:
            from rich.console import Console
            from rich.progress import (
                BarColumn,
                MofNCompleteColumn,
                Progress,
                TextColumn,
                TimeRemainingColumn,
            )
        except ModuleNotFoundError:
            return
        console = Console(stderr=True)
        self.progress = Progress(
            TextColumn("replay"),
            BarColumn(),
            MofNCompleteColumn(),
            TimeRemainingColumn(),
            console=console,
            disable=disabled or not console.is_terminal,
        )
        self.task = self.progress.add_task("frames", total=total)

    def __enter__(self) -> _Advance:
        if self.progress is not None:
            self.progress.start()
        return _Advance(self)

    def __exit__(self, *exc: object) -> None:
        if self.progress is not None:
            self.progress.stop()


class _Advance:
    def __init__(self, owner: _progress) -> None:
        self.owner = owner

    def __call__(self, n: int) -> None:
        if self.owner.progress is not None:
            self.owner.progress.advance(self.owner.task, n)
