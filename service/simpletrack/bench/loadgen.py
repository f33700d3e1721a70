"""The load generator of ``simpletrack bench service``: S sensors publishing detection frames at
a fixed rate, and the planner-side subscriber that times the track frames coming back.

It runs in its own process (started with multiprocessing's ``spawn``: never fork after
``zenoh.open``), with one Zenoh session for the publishers and the subscriber, so a frame's
latency is two readings of ONE clock, ``time.monotonic_ns()``: just before the publisher's
``put``, and on the subscriber's receipt of the track frame with the same sensor and ``seq``.
A load spread over several such processes (bench/generators.py) gives each a block of the
sensors (``LoadSpec.part`` of ``parts``, bench/shares.py); each subscribes to its own
sensors' answers only, so the two readings stay in the process that published the frame.

Protocol with the parent over a ``Connection``: child sends ``("ready", info)``, waits for
``"go"``, sends ``("start", t)`` when the warm-up ends and ``("end", t)`` after the last put,
then ``("result", dict)`` once every answer arrived or ``drain_s`` passed. The result holds
the process's own CPU time and how late its puts ran against their schedule over the
measured window (``generator``): what tells a step the generator could not offer.

With ``record_answers`` the result also holds every track frame received, duplicates
included, as ``(sensor, seq, instance, receipt ns)``, and each put's time: what the scale
benchmark needs to tell which member answered which frame around a fault.
"""

from __future__ import annotations

import contextlib
import math
import os
import threading
import time
from collections import Counter
from dataclasses import dataclass
from multiprocessing.connection import Connection
from pathlib import Path
from typing import Any

import msgpack
import numpy as np
import zenoh
from zenoh import ext

from simpletrack.bench.shares import chunk_patterns, split_sensors
from simpletrack.client.publisher import DEFAULT_HEARTBEAT_S
from simpletrack.core.boxes import Boxes
from simpletrack.datasets.kitti import camera_to_tracker
from simpletrack.datasets.nuscenes import TYPE_NAMES, scene_files
from simpletrack.session import open_session
from simpletrack.wire import BoxArrays
from simpletrack.wire.codec import pack
from simpletrack.wire.convert import boxes_to_wire
from simpletrack.wire.models import BoxColumns
from simpletrack.wire.reasons import DETECTION_SCHEMA_VERSION, SCHEMA_VERSION

# Every class the detector reports, as it reports them: the service drops the untracked ones.
ALL_CLASSES = tuple(TYPE_NAMES[t] for t in sorted(TYPE_NAMES))
UNTRACKED = ("construction_vehicle", "barrier", "traffic_cone")  # not in the nuscenes preset
FRAME_ID = "lidar"
SYNTHETIC_FRAMES = 20  # frames per synthetic stream before it cycles


@dataclass(frozen=True, slots=True)
class LoadSpec:
    endpoint: str
    prefix: str
    vehicle: str
    sensors: int
    rate_hz: float
    warmup_s: float
    seconds: float
    drain_s: float
    source: str  # "nuscenes" (real frames from `data`) or "synthetic"
    data: str  # the nuScenes centerpoint_val directory
    synthetic_boxes: int
    connect: tuple[str, ...] = ()  # further endpoints (other members of a group)
    record_answers: bool = False
    # Advanced publishers (cache, liveliness token), as DetectionPublisher declares: what a
    # group with subscribe = "owned" finds sensors by.
    advanced: bool = False
    # Their miss-detection heartbeat period (DetectionPublisher's heartbeat_s): each sends one
    # this often, whatever its rate, to every member subscribed to it.
    heartbeat_s: float = DEFAULT_HEARTBEAT_S
    # Fused vehicles instead of sensors: ``sensors`` vehicles, each a lidar (the scene's
    # frames) and a front camera (its view of them, half a period later), answered on the
    # vehicle's key (docs/SERVICE.md, "Vehicle fusion").
    fused: bool = False
    # This process's share of a load spread over several (bench/generators.py): block
    # ``part`` of split_sensors(sensors, parts); its rows and seqs keep their global numbers.
    part: int = 0
    parts: int = 1
    cpus: tuple[int, ...] = ()  # run on these CPUs only; () keeps the inherited affinity

    @property
    def streams(self) -> int:
        """Input streams: a sensor each, or a vehicle's two."""
        return self.sensors * self.per_sensor

    @property
    def per_sensor(self) -> int:
        return len(FUSED_SENSORS) if self.fused else 1

    @property
    def own(self) -> range:
        """This process's sensors (vehicles when fused)."""
        return split_sensors(self.sensors, self.parts)[self.part]

    @property
    def rows(self) -> range:
        """This process's streams, as rows of the whole load."""
        return range(self.own.start * self.per_sensor, self.own.stop * self.per_sensor)

    @property
    def ticks(self) -> int:
        return math.ceil((self.warmup_s + self.seconds) * self.rate_hz)

    @property
    def warm_ticks(self) -> int:
        return math.ceil(self.warmup_s * self.rate_hz)


FUSED_SENSORS = ("lidar", "camera")
IDENTITY = np.eye(4).reshape(-1).tolist()


def sensor_name(i: int) -> str:
    return f"s{i:04d}"


def vehicle_name(prefix: str, i: int) -> str:
    return f"{prefix}{i:04d}"


def stream_key(spec: LoadSpec, row: int) -> str:
    """Stream ``row``'s detections key: sensor ``row`` of the vehicle, or (fused) sensor
    ``row % 2`` of vehicle ``row // 2``."""
    if not spec.fused:
        return f"{spec.prefix}/{spec.vehicle}/{sensor_name(row)}/detections"
    sensor = FUSED_SENSORS[row % len(FUSED_SENSORS)]
    return f"{spec.prefix}/{vehicle_name(spec.vehicle, row // 2)}/{sensor}/detections"


def answer_keys(spec: LoadSpec, leaf: str) -> list[str]:
    """The key expressions this process hears ``leaf`` (tracks, errors) on: every sensor's
    when it holds the whole load; else its own block's only, so no other process's answers
    reach it (and cost it nothing)."""
    if spec.fused:
        names = ["*"] if spec.parts == 1 else chunk_patterns(spec.vehicle, spec.own)
        sensor = "@vehicle" if leaf == "tracks" else "*"  # a vehicle answers on its own key
        return [f"{spec.prefix}/{name}/{sensor}/{leaf}" for name in names]
    names = ["*"] if spec.parts == 1 else chunk_patterns("s", spec.own)
    return [f"{spec.prefix}/{spec.vehicle}/{name}/{leaf}" for name in names]


def front_view(columns: dict[str, Any]) -> dict[str, Any]:
    """What a front camera at the origin sees of a frame (bench/fused.py ``in_front_view``)."""
    from simpletrack.bench.fused import in_front_view  # the vehicle tracker: at set-up only

    center = np.frombuffer(columns["center"], np.float32).reshape(-1, 3)
    keep = in_front_view(center[:, 0], center[:, 1])
    out = dict(columns)
    out["count"] = int(keep.sum())
    for name, width in (("class_index", 1), ("center", 3), ("size", 3), ("yaw", 1)):
        dtype = np.int32 if name == "class_index" else np.float32
        arr = np.frombuffer(columns[name], dtype).reshape(-1, width)[keep]
        out[name] = np.ascontiguousarray(arr).tobytes()
    out["score"] = np.frombuffer(columns["score"], np.float64)[keep].tobytes()
    if "velocity" in columns:
        out["velocity"] = (
            np.frombuffer(columns["velocity"], np.float32).reshape(-1, 2)[keep].tobytes()
        )
    return out


# ----------------------------------------------------------------------------- frames
def scene_box_arrays(path: Path) -> list[BoxArrays]:
    """Every frame of a nuScenes detection file, every class, as the wire's box columns."""
    raw = np.loadtxt(path, delimiter=",", ndmin=2)
    frame = raw[:, 0].astype(np.int64)
    params = camera_to_tracker(raw[:, 7:14])
    order = np.argsort(frame, kind="stable")
    raw, frame, params = raw[order], frame[order], params[order]
    bounds = np.searchsorted(frame, np.arange(int(frame.max()) + 2))
    out = []
    for k in range(int(frame.max()) + 1):
        rows = slice(bounds[k], bounds[k + 1])
        boxes = Boxes.from_arrays(params[rows], raw[rows, 6], raw[rows, 1].astype(np.int32) - 1)
        out.append(boxes_to_wire(boxes, ALL_CLASSES))
    return out


def synthetic_box_arrays(n: int, seed: int) -> list[BoxArrays]:
    from simpletrack.bench.core import synthetic_stream  # the sweep's moving grid of cars

    return [
        boxes_to_wire(f.boxes, ("car",)) for f in synthetic_stream(n, SYNTHETIC_FRAMES, seed=seed)
    ]


def box_columns(boxes: BoxArrays) -> dict[str, Any]:
    """The ``boxes`` map of a DetectionFrame, built once per frame and reused on every send."""
    return BoxColumns.from_box_arrays(boxes).model_dump(mode="python", exclude_none=True)


def detection_payload(
    vehicle: str,
    sensor: str,
    seq: int,
    stamp_ns: int,
    columns: dict[str, Any],
    extrinsic: list[float] | None = None,
) -> bytes:
    """Byte for byte ``schemas.encode_detection_frame`` (a test checks), minus re-encoding the
    box columns on every send: at 5000 frames/s that cost would be the load generator's."""
    frame: dict[str, Any] = {
        "schema_version": SCHEMA_VERSION if extrinsic is None else DETECTION_SCHEMA_VERSION,
        "vehicle": vehicle,
        "sensor": sensor,
        "seq": seq,
        "stamp_ns": stamp_ns,
        "frame_id": FRAME_ID,
        "key_frame": True,
        "boxes": columns,
    }
    if extrinsic is not None:
        frame["extrinsic"] = extrinsic
    return pack(frame)


def peek(payload: bytes, field: str) -> Any:
    """One top-level field of a msgpack map without unpacking the (large) columns: the
    header fields come first in every message of the schema."""
    unpacker = msgpack.Unpacker(raw=False)
    unpacker.feed(payload[:512])
    try:
        for _ in range(unpacker.read_map_header()):
            key = unpacker.unpack()
            if key == field:
                return unpacker.unpack()
            unpacker.skip()
    except (msgpack.OutOfData, ValueError):
        pass
    obj = msgpack.unpackb(payload, raw=False)
    return obj.get(field) if isinstance(obj, dict) else None


def load_streams(spec: LoadSpec) -> list[list[dict[str, Any]]]:
    """Box columns per frame for each distinct stream; sensor i replays stream i % len (a
    fused vehicle: each frame's columns by sensor, the camera's its front view)."""
    if spec.source == "synthetic":
        n = min(spec.sensors, 4)
        out = [
            [box_columns(b) for b in synthetic_box_arrays(spec.synthetic_boxes, s)]
            for s in range(n)
        ]
    else:
        files = list(scene_files(Path(spec.data)))[: spec.sensors]
        out = [[box_columns(b) for b in scene_box_arrays(p)] for p in files]
    if spec.fused:  # each frame: the lidar's columns and the camera's, in FUSED_SENSORS order
        return [[{"lidar": c, "camera": front_view(c)} for c in stream] for stream in out]
    return out


# ----------------------------------------------------------------------------- the run
class Receiver:
    """Subscriber callbacks: receipt times by (this process's row, seq), errors by reason."""

    def __init__(self, spec: LoadSpec) -> None:
        self.spec = spec
        self.rows = spec.rows  # this process's, as rows of the whole load
        self.first = self.rows.start
        shape = (len(spec.rows), spec.ticks)
        self.recv_ns = np.zeros(shape, np.int64)
        # The answer's way back: receipt minus the service's published_ns, both wall clock
        # on this one host. Long while the service keeps up: this process heard late.
        self.back_ns = np.zeros(shape, np.int64)
        self.backed = np.zeros(shape, np.bool_)
        self.refused = np.zeros(shape, np.bool_)
        self.reasons: Counter[str] = Counter()
        self.received = 0
        self.errors = 0
        self.unexpected = 0
        self.window_start: int | None = None  # monotonic ns when the warm-up ended
        self.in_window = 0  # track frames received since window_start
        # With spec.record_answers: (the whole load's row, seq, instance, receipt ns).
        self.answers: list[tuple[int, int, str, int]] = []
        # And each refusal naming a frame: (the whole load's row, seq, reason).
        self.refusals: list[tuple[int, int, str]] = []
        # The threads the callbacks run in (one per subscriber): with the publishing thread,
        # the ones that share this process's interpreter lock.
        self.threads: set[int] = set()
        self.lock = threading.Lock()

    def _index(self, sample: zenoh.Sample, payload: bytes) -> tuple[int, int] | None:
        """(this process's row, seq) of a tracks or errors sample; None for a stream of
        another process (its subscriptions should never bring one)."""
        parts = str(sample.key_expr).split("/")
        try:
            if not self.spec.fused:
                row, seq = int(parts[-2][1:]), int(peek(payload, "seq"))
            else:
                vehicle = int(parts[-3][-4:])
                sensor = parts[-2]
                if sensor == "@vehicle":  # a fused message: the frame it answers
                    sensor, seq = str(peek(payload, "sensor")), int(peek(payload, "sensor_seq"))
                else:
                    seq = int(peek(payload, "seq"))
                row = vehicle * len(FUSED_SENSORS) + FUSED_SENSORS.index(sensor)
        except (ValueError, TypeError, IndexError):
            return None
        if row in self.rows and 0 <= seq < self.spec.ticks:
            return row - self.first, seq
        return None

    def on_tracks(self, sample: zenoh.Sample) -> None:
        now, wall = time.monotonic_ns(), time.time_ns()
        self.threads.add(threading.get_native_id())
        payload = sample.payload.to_bytes()
        at = self._index(sample, payload)
        instance = str(peek(payload, "instance")) if self.spec.record_answers else ""
        published = peek(payload, "published_ns")  # none from the echo
        with self.lock:
            if at is not None and self.spec.record_answers:
                self.answers.append((self.first + at[0], at[1], instance, now))
            if at is None or self.recv_ns[at]:
                self.unexpected += 1
                return
            self.recv_ns[at] = now
            if isinstance(published, int):
                self.back_ns[at] = wall - published
                self.backed[at] = True
            self.received += 1
            if self.window_start is not None and self.window_start <= now:
                self.in_window += 1

    def _named(self, sample: zenoh.Sample, payload: bytes) -> list[tuple[int, int]]:
        """The frames of this process a refusal names: its ``seq``, or every one of its
        ``seqs`` (a notice of frames shed under load names them all, the first as ``seq``)."""
        at = self._index(sample, payload)
        if at is None:
            return []
        seqs = peek(payload, "seqs")
        if not isinstance(seqs, list):
            return [at]
        row, ticks = at[0], self.spec.ticks
        return [(row, s) for s in seqs if isinstance(s, int) and 0 <= s < ticks]

    def on_errors(self, sample: zenoh.Sample) -> None:
        self.threads.add(threading.get_native_id())
        payload = sample.payload.to_bytes()
        reason = str(peek(payload, "reason"))
        named = self._named(sample, payload)
        with self.lock:
            # A refusal per frame named (one naming none of this load's frames counts once).
            self.errors += max(1, len(named))
            self.reasons[reason] += max(1, len(named))
            for at in named:
                self.refused[at] = True
                if self.spec.record_answers:
                    self.refusals.append((self.first + at[0], at[1], reason))

    def answered(self) -> int:
        """Frames answered by tracks or a refusal naming them. Not tracks plus errors: a
        frame both answered and named in a notice (a failover's) counted twice, and the wait
        for the last answers ended while the run's last frame was still on its way back
        (it was then counted unanswered)."""
        with self.lock:
            return int(np.count_nonzero((self.recv_ns != 0) | self.refused))


I64 = np.ndarray[Any, np.dtype[np.int64]]


def phases(spec: LoadSpec, period_ns: int) -> list[int]:
    """Each of this process's streams' offset in the period. Its sensors spread evenly over
    the whole period (not a 1/parts slice of it, which would ask the whole load's put rate of
    one process), shifted so the processes' puts interleave: the service sees the arrivals
    of one generator. A fused vehicle's camera comes half a period after its lidar."""
    m, parts, part = len(spec.own), spec.parts, spec.part
    if spec.fused:
        half = period_ns // 2
        return [
            (i // 2 * parts + part) * half // (m * parts) + (i % 2) * half
            for i in range(len(spec.rows))
        ]
    return [(j * parts + part) * period_ns // (m * parts) for j in range(m)]


@dataclass(slots=True)
class Schedule:
    """What the puts of one process measured; arrays by (this process's row, tick)."""

    sent_ns: I64  # just before each put
    late_ns: I64  # how far behind its due time each put started
    put_ns: I64  # time inside each put: long when Zenoh blocks (BLOCK congestion control)
    cpu_s: float  # the process's CPU time, every thread, over the measured window
    python_cpu_s: float  # of which its Python threads' (publishing, callbacks)
    window_s: float  # the measured window: the warm-up's end to the last put


CLK_TCK = os.sysconf("SC_CLK_TCK")


def thread_cpu() -> dict[int, float]:
    """CPU seconds (utime + stime) of each thread of this process, by native id."""
    out = {}
    for tid in os.listdir("/proc/self/task"):
        with contextlib.suppress(OSError):  # a thread that ended meanwhile
            text = Path(f"/proc/self/task/{tid}/stat").read_text()
            fields = text[text.rindex(")") + 2 :].split()
            out[int(tid)] = (int(fields[11]) + int(fields[12])) / CLK_TCK
    return out


def _publish(
    spec: LoadSpec,
    pubs: list[Any],  # zenoh.Publisher or an advanced one: both put
    streams: list[list[dict[str, Any]]],
    recv: Receiver,
    conn: Connection,
) -> Schedule:
    """Puts on schedule: stream i at tick k is due at t0 + k / rate + phases[i] (a fused
    vehicle's camera half a period after its lidar, stamped so)."""
    rows, ticks = spec.rows, spec.ticks
    n = len(rows)
    period_ns = int(1e9 / spec.rate_hz)
    sent_ns = np.zeros((n, ticks), np.int64)
    late_ns = np.zeros((n, ticks), np.int64)
    put_ns = np.zeros((n, ticks), np.int64)
    stamp0 = time.time_ns()
    t0 = time.monotonic_ns() + 50_000_000
    offsets = phases(spec, period_ns)
    # In time order: a fused vehicle's camera is due after the next vehicles' lidars, and a
    # put made in row order would run that late (counted as the generator's lag).
    order = sorted(range(n), key=offsets.__getitem__)
    names = [stream_key(spec, g).split("/") for g in rows]
    frames_of = [streams[(g // 2 if spec.fused else g) % len(streams)] for g in rows]
    extrinsic = IDENTITY if spec.fused else None
    start = cpu0 = 0
    threads0: dict[int, float] = {}
    for k in range(ticks):
        if k == spec.warm_ticks:
            start, cpu0, threads0 = time.monotonic_ns(), time.process_time_ns(), thread_cpu()
            with recv.lock:
                recv.window_start = start
            conn.send(("start", start))
        for i in order:
            due = t0 + k * period_ns + offsets[i]
            wait = due - time.monotonic_ns()
            if wait > 0:
                time.sleep(wait * 1e-9)
            frames = frames_of[i]
            columns = frames[k % len(frames)]
            if spec.fused:
                columns = columns[FUSED_SENSORS[rows[i] % 2]]
            payload = detection_payload(
                names[i][-3], names[i][-2], k, stamp0 + k * period_ns + offsets[i] % period_ns
                if spec.fused else stamp0 + k * period_ns, columns, extrinsic,
            )  # fmt: skip
            now = time.monotonic_ns()
            pubs[i].put(payload)
            sent_ns[i, k] = now
            late_ns[i, k] = now - due
            put_ns[i, k] = time.monotonic_ns() - now
    end = time.monotonic_ns()
    cpu_s = (time.process_time_ns() - cpu0) * 1e-9
    threads1 = thread_cpu()
    conn.send(("end", end))
    python = {threading.get_native_id()} | recv.threads
    python_s = sum(threads1.get(t, 0.0) - threads0.get(t, 0.0) for t in python)
    return Schedule(sent_ns, late_ns, put_ns, cpu_s, python_s, (end - start) * 1e-9)


def thread_cpus() -> list[int]:
    """The CPUs any thread of this process may run on (Zenoh's included)."""
    out: set[int] = set()
    for tid in os.listdir("/proc/self/task"):
        with contextlib.suppress(OSError):  # a thread that ended meanwhile
            out |= os.sched_getaffinity(int(tid))
    return sorted(out)


def generator_figures(spec: LoadSpec, sched: Schedule, recv: Receiver) -> dict[str, Any]:
    """This process's own cost and punctuality over the measured window: the evidence for
    (or against) the generator having limited a step (generators.generator_verdict); and
    its own frames' count, answers, and answers it should never have heard."""
    w = spec.warm_ticks
    late_ms = sched.late_ns[:, w:].reshape(-1) * 1e-6
    back_ms = recv.back_ns[:, w:][recv.backed[:, w:]] * 1e-6
    window = max(sched.window_s, 1e-9)
    period_ms = 1e3 / spec.rate_hz
    return {
        "process": spec.part,
        "sensors": [spec.own.start, spec.own.stop],  # [first, last + 1)
        "cpus": thread_cpus(),
        "sent": int(sched.sent_ns.size),
        "received": recv.received,
        "refused": recv.errors,
        "unexpected": recv.unexpected,
        "cpu_s": round(sched.cpu_s, 4),
        "window_s": round(sched.window_s, 4),
        "cores": round(sched.cpu_s / window, 4),
        # The part one interpreter lock serialises: what caps a process near one core, while
        # Zenoh's own threads (about half the process's CPU here) run beside it.
        "python_cores": round(sched.python_cpu_s / window, 4),
        "puts": int(late_ms.size),
        "lag_p99_ms": round(float(np.percentile(late_ms, 99)), 3) if late_ms.size else 0.0,
        "lag_max_ms": round(float(late_ms.max()), 3) if late_ms.size else 0.0,
        "late_puts": int((late_ms > period_ms).sum()),  # more than one period behind
        "put_share": round(float(sched.put_ns[:, w:].sum()) * 1e-9 / window, 4),
        "answer_lag_p99_ms": (
            round(float(np.percentile(back_ms, 99)), 3) if back_ms.size else None
        ),
    }


def _result(spec: LoadSpec, sched: Schedule, recv: Receiver) -> dict[str, Any]:
    w = spec.warm_ticks
    sent_ns = sched.sent_ns
    with recv.lock:
        got = recv.recv_ns[:, w:]
        ok = got > 0
        latency_s = ((got - sent_ns[:, w:])[ok] * 1e-9).astype(np.float64)
        # The worst frame of each tick: shows whether slow frames cluster in time (a stall
        # of the whole server) or are spread out (per-frame cost).
        per_tick = np.where(ok, (got - sent_ns[:, w:]) * 1e-6, 0.0).max(axis=0, initial=0.0)
        refused_window = int(recv.refused[:, w:].sum())
        return {
            "sent": int(sent_ns.size),
            "received": recv.received,
            "refused": recv.errors,
            "refused_by_reason": dict(recv.reasons),
            # Frames neither tracked nor named by a refusal: a frame refused by two members
            # of a group, or tracked and named in a failover's notice, counts once.
            "lost": int(sent_ns.size - np.count_nonzero((recv.recv_ns != 0) | recv.refused)),
            "unexpected": recv.unexpected,
            "window_sent": int(sent_ns[:, w:].size),
            "window_received": int(ok.sum()),
            "window_refused": refused_window,
            "received_during_window": recv.in_window,
            "latency_s": latency_s.tolist(),
            "worst_per_tick_ms": [round(float(v), 2) for v in per_tick],
            "put_lateness_s": (sched.late_ns[:, w:].reshape(-1) * 1e-9).tolist(),
            "loadgen_cpu_s": sched.cpu_s,
            "window_s": sched.window_s,
            "generator": generator_figures(spec, sched, recv),
            **(
                {
                    "answers": list(recv.answers),
                    "refusals": list(recv.refusals),
                    "sent_ns": sent_ns.tolist(),
                }
                if spec.record_answers
                else {}
            ),
        }


def pin(cpus: tuple[int, ...]) -> None:
    """Every thread of this process onto ``cpus`` (threads started later inherit it): on
    Linux the affinity is per thread, and numpy's start-up may already have started some."""
    for tid in os.listdir("/proc/self/task"):
        os.sched_setaffinity(int(tid), cpus)


def run(conn: Connection, spec: LoadSpec) -> None:
    """The spawned process's entry point."""
    try:
        if spec.cpus:
            pin(spec.cpus)
        streams = load_streams(spec)
        recv = Receiver(spec)
        with open_session(mode="peer", connect=[spec.endpoint, *spec.connect]) as session:
            for key in answer_keys(spec, "tracks"):
                session.declare_subscriber(key, recv.on_tracks)
            for key in answer_keys(spec, "errors"):
                session.declare_subscriber(key, recv.on_errors)
            keys = [stream_key(spec, g) for g in spec.rows]
            block = zenoh.CongestionControl.BLOCK
            plain = [session.declare_publisher(k, congestion_control=block) for k in keys]
            pubs: list[Any] = plain
            if spec.advanced:  # the plain ones then only tell when a member listens
                pubs = [
                    ext.declare_advanced_publisher(
                        session,
                        k,
                        congestion_control=block,
                        cache=ext.CacheConfig(100),
                        sample_miss_detection=ext.MissDetectionConfig(
                            heartbeat=spec.heartbeat_s, sporadic_heartbeat=None
                        ),
                        publisher_detection=True,
                    )
                    for k in keys
                ]
            deadline = time.monotonic() + 30
            while not all(p.matching_status.matching for p in plain):  # type: ignore[attr-defined]
                if time.monotonic() > deadline:
                    raise RuntimeError("no subscriber matched the detection keys within 30 s")
                time.sleep(0.02)
            per_frame = [c for s in streams for c in s]
            if spec.fused:
                per_frame = [f[name] for f in per_frame for name in FUSED_SENSORS]
            boxes = [c["count"] for c in per_frame]
            conn.send(("ready", {"streams": len(streams), "boxes_mean": float(np.mean(boxes))}))
            if conn.recv() != "go":
                return
            sched = _publish(spec, pubs, streams, recv, conn)
            with recv.lock:
                in_window = recv.in_window
            deadline = time.monotonic() + spec.drain_s
            while recv.answered() < sched.sent_ns.size and time.monotonic() < deadline:
                time.sleep(0.02)
            result = _result(spec, sched, recv)
            result["received_during_window"] = in_window
        conn.send(("result", result))
    except Exception as exc:  # reported to the parent, which turns it into one line
        conn.send(("error", f"{type(exc).__name__}: {exc}"))
    finally:
        conn.close()
