"""A wire fuzz run against a real service (``simpletrack bench fuzz``): valid detection frames
mixed with mutated ones on many sensors. Every frame must be answered once (its track frame or
a ``FrameError`` on its sensor's keys), no answer may carry a non-finite number or fail to
decode, and the service must neither die nor log a traceback.

The service runs with lossless backpressure, so a frame is never shed and each one has exactly
one answer; the run counts answers per key, because a payload too broken to read has no seq.
"""

from __future__ import annotations

import resource
import tempfile
import threading
import time
from collections import Counter
from collections.abc import Callable
from dataclasses import asdict, dataclass, field
from typing import Any

import msgpack
import numpy as np
import zenoh

from simpletrack.bench.stats import status_mb
from simpletrack.session import ZenohOptions, open_session
from simpletrack.spawn import spawned_service
from simpletrack.wire.codec import Rejection, decode_message, decode_track_frame
from simpletrack.wire.codec import encode_detection_frame as encode
from simpletrack.wire.columns import BoxArrays
from simpletrack.wire.keys import Keys
from simpletrack.wire.models import FrameError

CLASSES = ("Car", "Pedestrian", "Cyclist")  # the kitti preset's
T0_NS = 1_700_000_000_000_000_000
PERIOD_NS = 100_000_000
Obj = dict[str, Any]


@dataclass
class FuzzReport:
    sensors: int
    sent: int = 0
    valid: int = 0
    mutated: int = 0
    tracked: int = 0
    rejected: dict[str, int] = field(default_factory=dict)
    unanswered: int = 0
    answered_twice: int = 0
    non_finite: int = 0
    undecodable_answers: int = 0
    internal_errors: int = 0
    tracebacks: int = 0
    service_died: bool = False
    seconds: float = 0.0
    service_peak_rss_mb: float = 0.0
    mutations: dict[str, int] = field(default_factory=dict)

    @property
    def clean(self) -> bool:
        return not (
            self.unanswered
            or self.answered_twice
            or self.non_finite
            or self.undecodable_answers
            or self.internal_errors
            or self.tracebacks
            or self.service_died
        )

    def as_dict(self) -> dict[str, Any]:
        return {**asdict(self), "clean": self.clean}


def valid_frame(vehicle: str, sensor: str, k: int, rng: np.random.Generator) -> bytes:
    """A few cars driving along +x, frame k at 10 Hz, with a little noise."""
    n = int(rng.integers(0, 6))
    center = np.column_stack([10.0 + k + 8.0 * np.arange(n), 4.0 * np.arange(n), np.full(n, 0.8)])
    center += rng.normal(0.0, 0.05, center.shape)
    boxes = BoxArrays(
        classes=CLASSES,
        class_index=rng.integers(0, 3, n).astype(np.int32),
        center=center.astype(np.float32),
        size=np.tile(np.array([4.0, 1.8, 1.6], np.float32), (n, 1)),
        yaw=rng.normal(0.0, 0.05, n).astype(np.float32),
        score=rng.uniform(0.3, 1.0, n),
    )
    return encode(
        vehicle=vehicle,
        sensor=sensor,
        seq=k,
        stamp_ns=T0_NS + k * PERIOD_NS,
        frame_id=sensor,
        boxes=boxes,
    )


_ODD_VALUES: tuple[Any, ...] = (
    None, True, -1, 2**63, 2**62, -(2**63), 1e308, float("nan"), float("inf"), "", "x" * 300,
    b"\x00" * 7, [], {}, [1.0] * 16, "fleet/*", "a\n", 3.4e38,
)  # fmt: skip
_ODD_FLOATS = np.array([np.nan, np.inf, -np.inf, 3.4e38, -3.4e38, 1e-45, 0.0, -0.0, 1e30])


def _odd(rng: np.random.Generator) -> Any:
    return _ODD_VALUES[int(rng.integers(len(_ODD_VALUES)))]


def _mutate_column(obj: Obj, rng: np.random.Generator) -> None:
    boxes = obj.get("boxes")
    if not isinstance(boxes, dict) or not boxes.get("count"):
        obj["boxes"] = _odd(rng)
        return
    name = str(rng.choice(["center", "size", "yaw", "score", "class_index", "velocity"]))
    count = int(boxes["count"])
    width = {"center": 3, "size": 3, "velocity": 2}.get(name, 1)
    if name == "class_index":
        boxes[name] = rng.integers(-5, 10, count).astype("<i4").tobytes()
        return
    dtype = "<f8" if name == "score" else "<f4"
    values = rng.choice(_ODD_FLOATS, count * width).astype(dtype)
    boxes[name] = values.tobytes()


def _mutations() -> dict[str, Callable[[bytes, Obj, np.random.Generator], bytes]]:
    def pack(obj: Obj) -> bytes:
        return bytes(msgpack.packb(obj, use_bin_type=True))

    def flip(raw: bytes, _: Obj, rng: np.random.Generator) -> bytes:
        data = bytearray(raw)
        for i in rng.integers(0, len(data), int(rng.integers(1, 8))):
            data[i] ^= int(rng.integers(1, 256))
        return bytes(data)

    def truncate(raw: bytes, _: Obj, rng: np.random.Generator) -> bytes:
        return raw[: int(rng.integers(0, len(raw)))]

    def garbage(raw: bytes, _: Obj, rng: np.random.Generator) -> bytes:
        return rng.bytes(int(rng.integers(0, 64))) if rng.random() < 0.5 else raw + rng.bytes(5)

    def drop_key(_: bytes, obj: Obj, rng: np.random.Generator) -> bytes:
        obj.pop(str(rng.choice(sorted(obj))), None)
        return pack(obj)

    def extra_key(_: bytes, obj: Obj, rng: np.random.Generator) -> bytes:
        obj[str(rng.choice(["speed", "boxes2", "SEQ", ""]))] = _odd(rng)
        return pack(obj)

    def odd_value(_: bytes, obj: Obj, rng: np.random.Generator) -> bytes:
        obj[str(rng.choice(sorted(obj)))] = _odd(rng)
        return pack(obj)

    def odd_column(_: bytes, obj: Obj, rng: np.random.Generator) -> bytes:
        _mutate_column(obj, rng)
        return pack(obj)

    def odd_count(_: bytes, obj: Obj, rng: np.random.Generator) -> bytes:
        if isinstance(obj.get("boxes"), dict):
            obj["boxes"]["count"] = int(rng.choice([-1, 2**31, 10**6, 7]))
        return pack(obj)

    def odd_pose(_: bytes, obj: Obj, rng: np.random.Generator) -> bytes:
        obj["pose"] = (
            [float(v) for v in rng.choice(_ODD_FLOATS, 16)] if rng.random() < 0.5 else _odd(rng)
        )
        return pack(obj)

    def replay(_: bytes, obj: Obj, rng: np.random.Generator) -> bytes:
        # An old frame again, a seq from far away, or a stamp in the past or future.
        key = str(rng.choice(["seq", "stamp_ns"]))
        obj[key] = (
            int(rng.choice([0, 1, 2**62, 2**63 - 1]))
            if key == "seq"
            else int(rng.choice([0, T0_NS, T0_NS + 10**18]))
        )
        return pack(obj)

    def other_sensor(_: bytes, obj: Obj, rng: np.random.Generator) -> bytes:
        obj[str(rng.choice(["vehicle", "sensor"]))] = "someone-else"
        return pack(obj)

    return {
        f.__name__: f
        for f in (flip, truncate, garbage, drop_key, extra_key, odd_value, odd_column,
                  odd_count, odd_pose, replay, other_sensor)
    }  # fmt: skip


MUTATIONS = _mutations()


def mutate(raw: bytes, rng: np.random.Generator) -> tuple[str, bytes]:
    name = str(rng.choice(sorted(MUTATIONS)))
    obj: Obj = msgpack.unpackb(raw, raw=False)
    return name, MUTATIONS[name](raw, obj, rng)


class _Answers:
    """Answers per sensor key, counted and checked on Zenoh's callback threads."""

    def __init__(self, report: FuzzReport) -> None:
        self.report = report
        self.per_key: Counter[str] = Counter()
        self.lock = threading.Lock()

    def on_tracks(self, sample: zenoh.Sample) -> None:
        out = decode_track_frame(sample.payload.to_bytes())
        with self.lock:
            self.per_key[str(sample.key_expr).rsplit("/", 1)[0]] += 1
            if isinstance(out, Rejection):
                if out.reason.value == "non_finite":
                    self.report.non_finite += 1
                else:
                    self.report.undecodable_answers += 1
                return
            self.report.tracked += 1

    def on_error(self, sample: zenoh.Sample) -> None:
        err = decode_message(sample.payload.to_bytes(), FrameError)
        with self.lock:
            self.per_key[str(sample.key_expr).rsplit("/", 1)[0]] += 1
            if isinstance(err, Rejection):
                self.report.undecodable_answers += 1
                return
            reason = err.reason.value
            self.report.rejected[reason] = self.report.rejected.get(reason, 0) + 1
            self.report.internal_errors += reason == "internal_error"

    def total(self) -> int:
        with self.lock:
            return sum(self.per_key.values())


def _peak_rss_mb(pid: int) -> float:
    mb = status_mb(pid, "VmHWM")
    if mb is None:  # reaped already: the largest child's peak
        return float(resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss) / 1024
    return mb


def run_fuzz(
    frames: int,
    sensors: int = 20,
    mutated_share: float = 0.5,
    seed: int = 0,
    answer_timeout_s: float = 30.0,
    in_flight: int = 200,
) -> FuzzReport:
    """Send ``frames`` frames round-robin over ``sensors`` sensors, about ``mutated_share``
    of them mutated; wait for every answer (until none has come for ``answer_timeout_s``);
    report."""
    rng = np.random.default_rng(seed)
    report = FuzzReport(sensors=sensors)
    answers = _Answers(report)
    keys = Keys()
    sent: Counter[str] = Counter()
    mutations: Counter[str] = Counter()
    started = time.monotonic()
    with (
        tempfile.TemporaryFile() as log,
        spawned_service("kitti", log=log) as svc,
        open_session(ZenohOptions(connect=[svc.endpoint])) as session,
        session.declare_subscriber(f"{keys.prefix}/*/*/tracks", answers.on_tracks),
        session.declare_subscriber(f"{keys.prefix}/*/*/errors", answers.on_error),
    ):
        names = [(f"fuzz-{i // 2:03d}", "lidar" if i % 2 == 0 else "radar") for i in range(sensors)]
        pubs = {
            name: session.declare_publisher(
                keys.detections(*name), congestion_control=zenoh.CongestionControl.BLOCK
            )
            for name in names
        }
        time.sleep(0.5)  # the subscriptions reach the service, and its answers reach ours
        next_k = dict.fromkeys(names, 0)
        for i in range(frames):
            name = names[i % sensors]
            payload = valid_frame(*name, next_k[name], rng)
            next_k[name] += 1
            if rng.random() < mutated_share:
                kind, payload = mutate(payload, rng)
                mutations[kind] += 1
            # A bounded number in flight: the run tests what every frame gets, not overload
            # (a backlog the service cannot drain for seconds is shed by Zenoh itself).
            while i - answers.total() >= in_flight and svc.proc.poll() is None:
                time.sleep(0.0005)
            pubs[name].put(payload)
            sent[f"{keys.prefix}/{name[0]}/{name[1]}"] += 1
        report.sent = frames
        report.mutated = sum(mutations.values())
        report.valid = frames - report.mutated
        # The service may still be working through a backlog: wait while answers keep coming.
        seen, progress_at = 0, time.monotonic()
        while (got := answers.total()) < frames and svc.proc.poll() is None:
            if got > seen:
                seen, progress_at = got, time.monotonic()
            elif time.monotonic() - progress_at > answer_timeout_s:
                break
            time.sleep(0.05)
        time.sleep(0.5)  # anything answered twice arrives too
        report.service_died = svc.proc.poll() is not None
        report.service_peak_rss_mb = round(_peak_rss_mb(svc.proc.pid), 1)
        with answers.lock:
            for key, n in sent.items():
                got = answers.per_key.get(key, 0)
                report.unanswered += max(0, n - got)
                report.answered_twice += max(0, got - n)
        log.seek(0)
        report.tracebacks = log.read().decode(errors="replace").count("Traceback")
    report.seconds = round(time.monotonic() - started, 1)
    report.mutations = dict(sorted(mutations.items()))
    report.rejected = dict(sorted(report.rejected.items()))
    return report


def format_report(r: FuzzReport) -> str:
    lines = [
        f"fuzz: {r.sent} frames on {r.sensors} sensors in {r.seconds} s "
        f"({r.valid} valid, {r.mutated} mutated); service peak RSS {r.service_peak_rss_mb} MB",
        f"  answered   {r.tracked} tracked, {sum(r.rejected.values())} refused, "
        f"{r.unanswered} unanswered, {r.answered_twice} answered twice",
        f"  faults     {(r.service_died and 'service died') or 'service alive'}, "
        f"{r.tracebacks} tracebacks, {r.internal_errors} internal errors, "
        f"{r.non_finite} non-finite answers, {r.undecodable_answers} undecodable answers",
        "  refused    " + ", ".join(f"{k} {v}" for k, v in r.rejected.items()),
        "  mutations  " + ", ".join(f"{k} {v}" for k, v in r.mutations.items()),
        f"  verdict    {'clean' if r.clean else 'NOT CLEAN'}",
    ]
    return "\n".join(lines)
