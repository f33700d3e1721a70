"""``simpletrack replay mcap FILE``: publish a recording's detection payloads, bytes as
recorded, back onto Zenoh at the recorded pace, a chosen rate, or as fast as the service
keeps up.

A recording of a fused vehicle holds its sensors' detections (with their extrinsics or poses)
and its fused tracks (``<vehicle>/@vehicle/tracks``). Only the detections are sent: the
service makes the fused tracks again. A fused sensor's frame gets no answer of its own (the
vehicle publishes one message per frame it applies, in stamp order; a frame it only watches or
re-processes gets none): it counts as answered once the vehicle's tracks reach its stamp
(``Watermarks``)."""

from __future__ import annotations

import argparse
import heapq
import struct
import sys
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import zenoh

from simpletrack.cli.common import check_prefix, client_options, open_client_session
from simpletrack.cli.errors import UserError
from simpletrack.cli.record_mcap import parse_sensors
from simpletrack.cli.replay import Answers, _progress, parse_rate
from simpletrack.client.publisher import CONGESTION, MSGPACK
from simpletrack.client.subscriber import (
    TrackSubscriber,
    VehicleTrackMessage,
    VehicleTrackSubscriber,
)
from simpletrack.mcap.format import MESSAGE_ENCODING, ROS2_PROFILE, split_key
from simpletrack.mcap.reader import McapError, read
from simpletrack.session import Congestion
from simpletrack.wire import FrameError, Rejection, decode_message
from simpletrack.wire.header import peek_header
from simpletrack.wire.keys import DETECTIONS, VEHICLE_STREAM, Keys


@dataclass(frozen=True, slots=True)
class Recorded:
    prefix: str
    vehicle: str
    sensor: str
    log_time: int
    seq: int | None
    payload: bytes
    stamp_ns: int | None = None


def load(path: Path, sensors: list[tuple[str, str]] | None) -> list[Recorded]:
    """Every detections message of the recording (of ``sensors`` when given), in log time
    order; never a fused vehicle's tracks (``@vehicle``), its twins or any other channel. Read
    whole before anything is sent, so a damaged file fails before the first frame."""
    if not path.is_file():
        raise UserError(f"{path}: no such file")
    try:
        recording = read(path)
    except (McapError, OSError, struct.error, UnicodeDecodeError) as exc:
        raise UserError(f"{path}: not a readable MCAP file ({exc})") from None
    except Exception as exc:  # a damaged LZ4 or zstd chunk (their errors have no common base)
        raise UserError(f"{path}: not a readable MCAP file ({type(exc).__name__}: {exc})") from None
    profile = recording.profile
    out: list[Recorded] = []
    for message in recording.messages:
        channel = message.channel
        parts = split_key(channel.topic)
        if parts is None or parts[3] != DETECTIONS or channel.message_encoding != MESSAGE_ENCODING:
            continue
        seq, stamp = peek_header(message.data)
        out.append(Recorded(*parts[:3], message.log_time, seq, message.data, stamp))
    if not out and profile == ROS2_PROFILE:
        raise UserError(
            f"{path}: a ROS 2 bag (profile {ROS2_PROFILE}, such as record's --ros2 writes), not "
            "a recording of the wire's messages: replay the recording it was written beside"
        )
    if not out:
        raise UserError(f"{path}: no detections channels (record with --what detections)")
    if sensors is not None:
        found = sorted({f"{r.vehicle}/{r.sensor}" for r in out})
        for v, s in sensors:
            if not any(_match(v, r.vehicle) and _match(s, r.sensor) for r in out):
                raise UserError(f"--sensors {v}/{s}: not in {path}; recorded: {', '.join(found)}")
        out = [
            r for r in out if any(_match(v, r.vehicle) and _match(s, r.sensor) for v, s in sensors)
        ]
    return out


def _match(pattern: str, name: str) -> bool:
    return pattern in ("*", name)


class Watermarks:
    """Which sent frames of fused sensors a vehicle's tracks answered. A vehicle applies its
    fused sensors' frames in stamp order and publishes one message per frame applied, stamped
    with it: once a message at stamp T came, every frame of its ``sensors`` stamped at or
    before T has been taken (applied, watched, or re-processed into place), though most get
    no message of their own. Frames of vehicles or sensors not (yet) heard fused wait here;
    a sensor tracked on its own is answered by its own tracks instead."""

    def __init__(self) -> None:
        # (vehicle, sensor) -> heap of (stamp_ns, seq) of frames sent and not yet passed.
        self._pending: dict[tuple[str, str], list[tuple[int, int]]] = {}
        # vehicle -> (the highest stamp its tracks reached, its fused sensors)
        self._marks: dict[str, tuple[int, frozenset[str]]] = {}

    def sent(self, vehicle: str, sensor: str, seq: int, stamp_ns: int) -> bool:
        """Records a frame going out; True when the vehicle's tracks already passed its stamp
        (a frame the vehicle will re-process, or refuse as late: no message of its own)."""
        mark = self._marks.get(vehicle)
        if mark is not None and sensor in mark[1] and stamp_ns <= mark[0]:
            return True
        heapq.heappush(self._pending.setdefault((vehicle, sensor), []), (stamp_ns, seq))
        return False

    def heard(self, vehicle: str, sensors: list[str], stamp_ns: int) -> list[tuple[str, str, int]]:
        """A vehicle's tracks message at ``stamp_ns``: the (vehicle, sensor, seq) of the frames
        it answers."""
        mark = max(stamp_ns, self._marks.get(vehicle, (stamp_ns, frozenset()))[0])
        self._marks[vehicle] = (mark, frozenset(sensors))
        out = []
        for sensor in sensors:
            heap = self._pending.get((vehicle, sensor))
            while heap and heap[0][0] <= mark:
                out.append((vehicle, sensor, heapq.heappop(heap)[1]))
        return out


def schedule(frames: list[Recorded], rate: float | str | None) -> list[tuple[float, Recorded]]:
    """(seconds from the start, frame) in sending order: the recorded log times, each
    stream's n-th frame at n / rate, or all at 0 ('max': paced by the window alone)."""
    if rate == "recorded":
        first = frames[0].log_time
        return [((r.log_time - first) / 1e9, r) for r in frames]
    if rate is None:
        return [(0.0, r) for r in frames]
    assert isinstance(rate, float)
    index: dict[tuple[str, str, str], int] = {}
    timed = []
    for order, r in enumerate(frames):
        stream = (r.prefix, r.vehicle, r.sensor)
        n = index[stream] = index.get(stream, -1) + 1
        timed.append((n / rate, order, r))
    timed.sort(key=lambda t: (t[0], t[1]))
    return [(t, r) for t, _, r in timed]


def run_mcap(args: argparse.Namespace) -> int:
    if args.file is None:
        raise UserError("replay mcap needs the recording: simpletrack replay mcap FILE.mcap")
    if args.data is not None:
        raise UserError("replay mcap reads FILE.mcap, not --data")
    for flag in ("seqs", "classes", "vehicle"):
        if getattr(args, flag) is not None:
            raise UserError(f"--{flag} applies to replay kitti and nuscenes, not mcap")
    if args.sensor != "{seq}":
        raise UserError("--sensor applies to replay kitti and nuscenes; mcap has --sensors")
    if args.window < 1:
        raise UserError(f"--window {args.window} must be at least 1")
    prefix = check_prefix(args.prefix) if args.prefix is not None else None
    sensors = parse_sensors(args.sensors) if args.sensors is not None else None
    for v, s in sensors or []:
        if s == VEHICLE_STREAM:
            raise UserError(
                f"--sensors {v}/{s}: a fused vehicle's tracks are not replayed (the service "
                f"makes them again from its sensors' detections: --sensors '{v}/*')"
            )
    text = args.rate.strip().lower() if args.rate is not None else "recorded"
    rate = "recorded" if text == "recorded" else parse_rate(args.rate, 0.0)
    frames = load(args.file, sensors)
    plan = schedule(frames, rate)
    options = client_options(args)
    congestion = CONGESTION[Congestion(args.congestion)]

    session = open_client_session(options)
    answers = Answers()
    marks = Watermarks()

    def on_vehicle(msg: VehicleTrackMessage) -> None:
        with answers.cond:  # one lock for the marks and the answers: no frame missed between
            answered = marks.heard(msg.vehicle, msg.sensors, msg.stamp_ns)
            answers.on_fused(answered)

    publishers: dict[str, zenoh.Publisher] = {}
    sent = 0
    started = time.monotonic()
    outcome = "done"
    try:
        prefixes = sorted({prefix or r.prefix for r in frames})
        listeners: list[TrackSubscriber | VehicleTrackSubscriber] = [
            TrackSubscriber(session, prefix=p, callback=answers.on_tracks) for p in prefixes
        ]
        listeners += [
            VehicleTrackSubscriber(session, prefix=p, callback=on_vehicle) for p in prefixes
        ]
        error_subs = [
            session.declare_subscriber(Keys(p).errors("*", "*"), _on_error(answers))
            for p in prefixes
        ]
        for r in frames:
            key = Keys(prefix or r.prefix).detections(r.vehicle, r.sensor)
            if key not in publishers:
                publishers[key] = session.declare_publisher(
                    key, encoding=MSGPACK, congestion_control=congestion
                )
        _wait_for_service(publishers, args.wait)
        with _progress(len(plan), args.no_progress) as advance:
            start = time.monotonic()
            for at, r in plan:
                delay = start + at - time.monotonic()
                if delay > 0:
                    time.sleep(delay)
                if not answers.wait_below(sent, args.window, args.answer_timeout):
                    outcome = "service stopped answering"
                    break
                if r.seq is not None and r.stamp_ns is not None:
                    with answers.cond:
                        if marks.sent(r.vehicle, r.sensor, r.seq, r.stamp_ns):
                            answers.on_fused([(r.vehicle, r.sensor, r.seq)])
                publishers[Keys(prefix or r.prefix).detections(r.vehicle, r.sensor)].put(r.payload)
                sent += 1
                advance(1)
        deadline = time.monotonic() + args.answer_timeout
        with answers.cond:
            while len(answers.answered) < sent and time.monotonic() < deadline:
                answers.cond.wait(0.2)
        for listener in listeners:
            listener.close()
        for sub in error_subs:
            sub.undeclare()  # type: ignore[no-untyped-call]
        for pub in publishers.values():
            pub.undeclare()  # type: ignore[no-untyped-call]
    except KeyboardInterrupt:
        outcome = "interrupted"
    finally:
        session.close()  # type: ignore[no-untyped-call]

    elapsed = time.monotonic() - started
    answered = answers.count()
    errors = sum(answers.errors.values())
    streams = len({(r.prefix, r.vehicle, r.sensor) for r in frames})
    print(
        f"replay mcap: {outcome}: {streams} stream(s), {sent}/{len(plan)} frames sent in "
        f"{elapsed:.1f} s ({sent / max(elapsed, 1e-9):.1f} frames/s), {answers.tracked} tracked"
        + (f" ({answers.fused} into fused vehicles' tracks)" if answers.fused else "")
        + f", {errors} refused, {max(sent - answered, 0)} unanswered"
    )
    for reason, n in sorted(answers.errors.items()):
        print(f"  refused {n} x {reason}")
    sys.stdout.flush()
    if outcome == "interrupted":
        return 130
    return 0 if (outcome == "done" and errors == 0 and answered >= sent) else 1


def _on_error(answers: Answers) -> Callable[[zenoh.Sample], None]:
    def on_sample(sample: zenoh.Sample) -> None:
        err = decode_message(sample.payload.to_bytes(), FrameError)
        if not isinstance(err, Rejection):
            answers.on_error(err)

    return on_sample


def _matching(pub: zenoh.Publisher) -> bool:
    # Typed as bool in the stubs, a MatchingStatus at run time (as in DetectionPublisher).
    status: object = pub.matching_status
    return bool(getattr(status, "matching", status))


def _wait_for_service(publishers: dict[str, zenoh.Publisher], timeout: float) -> None:
    deadline = time.monotonic() + timeout
    for key, pub in publishers.items():
        while not _matching(pub):
            if time.monotonic() >= deadline:
                raise UserError(
                    f"no service subscribed to {key} after {timeout:g} s "
                    "(is `simpletrack serve` running? check --connect and --prefix)"
                )
            time.sleep(0.02)
