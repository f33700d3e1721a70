"""Tracker workers: each owns a queue and the sensors hashed to it, and runs, per frame,
decode → ordering checks → tracker step → publish. One thread per worker keeps a sensor's
frames strictly in order; sensors on different workers never wait for each other.
"""

from __future__ import annotations

import contextlib
import re
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import zenoh

from simpletrack.core.boxes import Boxes
from simpletrack.core.frames import Frame, Tracks
from simpletrack.core.lifecycle import TrackState
from simpletrack.core.tracker import Tracker
from simpletrack.server.intake import Dropped, Inbound, WorkQueue
from simpletrack.server.logs import get_logger
from simpletrack.server.metrics import Metrics
from simpletrack.server.settings import Congestion, ServiceSettings
from simpletrack.server.snapshots import Batch, SnapshotWriter, snapshot_path
from simpletrack.wire.codec import (
    DecodedDetections,
    DecodeLimits,
    Rejection,
    decode_detection_frame,
    encode_track_frame,
)
from simpletrack.wire.codec import encode as encode_message
from simpletrack.wire.columns import TrackArrays
from simpletrack.wire.keys import Keys
from simpletrack.wire.models import NAME_PATTERN, FrameError, SensorSnapshot, SensorStatus
from simpletrack.wire.reasons import SCHEMA_VERSION, ErrorReason, WireTrackState

log = get_logger("pool")
NAME_RE = re.compile(NAME_PATTERN)
MSGPACK = zenoh.Encoding("application/msgpack")
MAX_RETIRED = 100_000  # id reservations of evicted sensors kept in memory
HOUSEKEEPING_S = 0.5


class SensorBudget:
    """Caps the sensors held in memory across all workers."""

    def __init__(self, limit: int) -> None:
        self.limit, self.used = limit, 0
        self._lock = threading.Lock()

    def acquire(self) -> bool:
        with self._lock:
            if self.used >= self.limit:
                return False
            self.used += 1
            return True

    def release(self) -> None:
        with self._lock:
            self.used -= 1


@dataclass
class Context:
    """What every worker shares (read-only after start, except the thread-safe parts)."""

    settings: ServiceSettings
    session: zenoh.Session
    keys: Keys
    metrics: Metrics
    tracker_config_digest: str
    new_tracker: Callable[[], Tracker]
    class_codes: dict[str, int]  # name -> tracker code; -1 for ignore_classes
    classes: tuple[str, ...]  # the tracks' class table
    budget: SensorBudget
    writer: SnapshotWriter | None
    limits: DecodeLimits = field(default_factory=DecodeLimits)

    @property
    def congestion(self) -> zenoh.CongestionControl:
        if self.settings.congestion_control is Congestion.BLOCK:
            return zenoh.CongestionControl.BLOCK
        return zenoh.CongestionControl.DROP

    def put(self, key: str, payload: bytes) -> None:
        self.session.put(key, payload, encoding=MSGPACK, congestion_control=self.congestion)


@dataclass
class SensorState:
    vehicle: str
    sensor: str
    tracker: Tracker
    id_base: int = 0  # wire id = id_base + tracker id; raised past every id on each reset
    last_seq: int | None = None
    last_stamp_ns: int | None = None
    stamp_origin_ns: int | None = None
    frames: int = 0
    active_tracks: int = 0
    last_seen: float = field(default_factory=time.monotonic)
    dirty: bool = True
    tracks_pub: zenoh.Publisher | None = None
    errors_pub: zenoh.Publisher | None = None

    @property
    def id_next(self) -> int:
        return self.id_base + self.tracker.next_id

    def reset(self, stamp_ns: int) -> None:
        self.id_base = self.id_next
        self.tracker.reset()
        self.stamp_origin_ns = stamp_ns

    def snapshot(self, digest: str, with_tracker: bool = True) -> SensorSnapshot:
        return SensorSnapshot(
            schema_version=SCHEMA_VERSION,
            vehicle=self.vehicle,
            sensor=self.sensor,
            last_seq=self.last_seq,
            last_stamp_ns=self.last_stamp_ns,
            stamp_origin_ns=self.stamp_origin_ns,
            id_base=self.id_base if with_tracker else self.id_next,
            id_next=self.id_next,
            frames=self.frames,
            config_digest=digest,
            tracker=self.tracker.to_bytes() if with_tracker else None,
            written_ns=time.time_ns(),
        )

    def undeclare(self) -> None:
        for pub in (self.tracks_pub, self.errors_pub):
            if pub is not None:
                with contextlib.suppress(zenoh.ZError):  # session already closed
                    pub.undeclare()  # type: ignore[no-untyped-call]
        self.tracks_pub = self.errors_pub = None


def tracks_to_wire(tracks: Tracks, id_base: int, classes: tuple[str, ...]) -> TrackArrays:
    p = tracks.boxes.params
    confirmed = tracks.state == TrackState.CONFIRMED
    state = np.where(
        confirmed,
        np.where(tracks.time_since_update > 0, WireTrackState.COASTING, WireTrackState.CONFIRMED),
        WireTrackState.TENTATIVE,
    ).astype(np.int32)
    return TrackArrays(
        classes=classes,
        id=tracks.ids + np.int64(id_base),
        class_index=tracks.boxes.cls.astype(np.int32),
        center=p[:, 0:3].astype(np.float32),
        size=p[:, 4:7].astype(np.float32),
        yaw=p[:, 3].astype(np.float32),
        score=tracks.boxes.score,
        velocity=tracks.velocity.astype(np.float32),
        state=state,
        hits=tracks.hits.astype(np.int32),
        age=tracks.age.astype(np.int32),
        time_since_update=tracks.time_since_update.astype(np.int32),
    )


def detections_to_frame(d: DecodedDetections, stamp: float) -> tuple[Frame, int]:
    """The tracker's frame (float64, z-up x, y, z, yaw, l, w, h) and how many boxes of
    ignored classes were left out."""
    b = d.boxes
    codes = d.codes if d.codes is not None else b.class_index
    keep = codes >= 0
    params = np.concatenate([b.center, b.yaw[:, None], b.size], axis=1).astype(np.float64)
    boxes = Boxes.from_arrays(params, b.score, codes, b.velocity)
    ignored = int(len(b) - int(keep.sum()))
    if ignored:
        boxes = boxes.take(keep)
    return Frame(boxes=boxes, stamp=stamp, pose=d.pose, key_frame=d.frame.key_frame), ignored


class Worker(threading.Thread):
    def __init__(self, index: int, queue: WorkQueue, ctx: Context) -> None:
        super().__init__(name=f"tracker-{index}", daemon=True)
        self.index, self.queue, self.ctx = index, queue, ctx
        self.sensors: dict[str, SensorState] = {}
        self.retired: dict[str, int] = {}  # evicted sensor -> lowest unused id
        self.drain_deadline: float | None = None
        self.snapshot_done_at = time.monotonic()
        self._next_snapshot = time.monotonic() + ctx.settings.snapshot_interval_s
        self._next_housekeeping = time.monotonic() + HOUSEKEEPING_S

    # ------------------------------------------------------------------ restore / status
    def adopt(self, snap: SensorSnapshot) -> None:
        """Take over a sensor from the state directory (before the thread starts)."""
        key = f"{snap.vehicle}/{snap.sensor}"
        if snap.tracker is None:
            self.retired[key] = snap.id_next
            return
        tracker: Tracker | None = None
        id_base = snap.id_base
        if snap.config_digest != self.ctx.tracker_config_digest:
            log.warning("snapshot_config_changed", vehicle=snap.vehicle, sensor=snap.sensor)
        else:
            try:
                tracker = Tracker.from_bytes(snap.tracker)
            except Exception:
                log.error(
                    "snapshot_tracker_unreadable",
                    exc=True,
                    vehicle=snap.vehicle,
                    sensor=snap.sensor,
                )
        if tracker is None:  # start afresh, but never reuse an id
            tracker, id_base = self.ctx.new_tracker(), snap.id_next
        if not self.ctx.budget.acquire():
            log.error("snapshot_over_max_sensors", vehicle=snap.vehicle, sensor=snap.sensor)
            self.retired[key] = snap.id_next
            return
        self.sensors[key] = SensorState(
            vehicle=snap.vehicle,
            sensor=snap.sensor,
            tracker=tracker,
            id_base=id_base,
            last_seq=snap.last_seq,
            last_stamp_ns=snap.last_stamp_ns,
            stamp_origin_ns=snap.stamp_origin_ns,
            frames=snap.frames,
            dirty=False,
        )
        self.ctx.metrics.restored.inc()
        self.ctx.metrics.active_sensors.inc()
        log.info(
            "sensor_restored",
            vehicle=snap.vehicle,
            sensor=snap.sensor,
            seq=snap.last_seq,
            id_next=snap.id_next,
        )

    def status(self) -> list[SensorStatus]:
        now = time.monotonic()
        return [
            SensorStatus(
                vehicle=s.vehicle,
                sensor=s.sensor,
                last_seq=s.last_seq,
                last_stamp_ns=s.last_stamp_ns,
                frames=s.frames,
                active_tracks=s.active_tracks,
                idle_s=round(now - s.last_seen, 3),
            )
            for s in list(self.sensors.values())
        ]

    def snapshot_of(self, vehicle: str, sensor: str) -> SensorSnapshot | None:
        """Only from this worker's thread (it owns the trackers): via ``queue.put_control``."""
        s = self.sensors.get(f"{vehicle}/{sensor}")
        return None if s is None else s.snapshot(self.ctx.tracker_config_digest)

    def sensor_names(self) -> list[tuple[str, str]]:
        return [(s.vehicle, s.sensor) for s in list(self.sensors.values())]

    # ------------------------------------------------------------------ the loop
    def run(self) -> None:
        while True:
            item = self.queue.get(timeout=HOUSEKEEPING_S)
            if item is None and self.queue.closed:
                break
            try:
                if isinstance(item, Inbound):
                    if self.drain_deadline is not None and time.monotonic() > self.drain_deadline:
                        self._drop(item, ErrorReason.DROPPED_SHUTDOWN)
                    else:
                        self._process(item)
                elif isinstance(item, Dropped):
                    self._drop(item.item, item.reason, counted=True)
                elif item is not None:
                    item()
                if time.monotonic() >= self._next_housekeeping:
                    self._housekeeping()
            except Exception:  # never let one frame kill the thread of many sensors
                log.error("worker_error", exc=True, worker=self.index)
        self._final_snapshot()
        for s in self.sensors.values():
            s.undeclare()

    def _housekeeping(self) -> None:
        now = time.monotonic()
        self._next_housekeeping = now + HOUSEKEEPING_S
        idle = self.ctx.settings.sensor_idle_s
        for key, s in list(self.sensors.items()):
            if now - s.last_seen > idle:
                self._evict(key, s)
        if now >= self._next_snapshot:
            self._next_snapshot = now + self.ctx.settings.snapshot_interval_s
            self._snapshot([s for s in self.sensors.values() if s.dirty])

    def _evict(self, key: str, s: SensorState) -> None:
        del self.sensors[key]
        self.retired[key] = s.id_next
        while len(self.retired) > MAX_RETIRED:
            del self.retired[next(iter(self.retired))]
        s.undeclare()
        self.ctx.budget.release()
        m = self.ctx.metrics
        m.evicted.inc()
        m.active_sensors.dec()
        m.active_tracks.dec(s.active_tracks)
        log.info(
            "sensor_evicted", vehicle=s.vehicle, sensor=s.sensor, seq=s.last_seq, id_next=s.id_next
        )
        self._write([(s, False)])

    def _snapshot(self, sensors: list[SensorState]) -> None:
        if sensors:
            self._write([(s, True) for s in sensors])
        else:
            self.snapshot_done_at = time.monotonic()

    def _final_snapshot(self) -> None:
        self._snapshot([s for s in self.sensors.values() if s.dirty])

    def _write(self, items: list[tuple[SensorState, bool]]) -> None:
        ctx = self.ctx
        if ctx.writer is None or ctx.settings.state_dir is None:
            return
        state_dir: Path = ctx.settings.state_dir
        files = []
        for s, with_tracker in items:
            snap = s.snapshot(ctx.tracker_config_digest, with_tracker)
            files.append((snapshot_path(state_dir, s.vehicle, s.sensor), encode_message(snap)))
            s.dirty = False

        def done(written: int, failed: int) -> None:
            ctx.metrics.snapshots.inc(written)
            if failed:
                ctx.metrics.snapshot_failures.inc(failed)
            else:
                self.snapshot_done_at = time.monotonic()

        ctx.writer.submit(Batch(files, done))

    # ------------------------------------------------------------------ one frame
    def _process(self, item: Inbound) -> None:
        ctx, m = self.ctx, self.ctx.metrics
        t0 = time.perf_counter()
        m.stage.labels(stage="queue").observe(t0 - item.received_at)
        vehicle, sensor = ctx.keys.sensor_of(item.key) or ("", "")
        if not (NAME_RE.match(vehicle) and NAME_RE.match(sensor)):
            # No errors key can be derived from a key like this: count and log only.
            m.count_error(ErrorReason.INVALID_VALUE, "")
            log.warning("frame_rejected", key=item.key, reason="invalid_value", field="key")
            return
        skey = f"{vehicle}/{sensor}"
        state = self.sensors.get(skey)

        decoded = decode_detection_frame(item.payload, ctx.limits, ctx.class_codes)
        t1 = time.perf_counter()
        m.stage.labels(stage="decode").observe(t1 - t0)
        if isinstance(decoded, Rejection):
            self._reject(item, vehicle, sensor, state, decoded)
            return
        frame = decoded.frame
        seq, stamp_ns = frame.seq, frame.stamp_ns
        if frame.vehicle != vehicle or frame.sensor != sensor:
            self._reject(
                item,
                vehicle,
                sensor,
                state,
                Rejection(
                    ErrorReason.KEY_MISMATCH,
                    "vehicle" if frame.vehicle != vehicle else "sensor",
                    f"payload says {frame.vehicle}/{frame.sensor}, key says {vehicle}/{sensor}",
                    seq,
                    stamp_ns,
                ),
            )
            return

        if state is None:
            if not ctx.budget.acquire():
                self._reject(
                    item,
                    vehicle,
                    sensor,
                    None,
                    Rejection(
                        ErrorReason.TOO_MANY_SENSORS,
                        None,
                        f"already tracking max_sensors={ctx.budget.limit} sensors",
                        seq,
                        stamp_ns,
                    ),
                )
                return
            state = SensorState(
                vehicle, sensor, ctx.new_tracker(), id_base=self.retired.pop(skey, 0)
            )
            self.sensors[skey] = state
            m.active_sensors.inc()
            log.info("sensor_added", vehicle=vehicle, sensor=sensor, seq=seq, id_base=state.id_base)
        elif (why := self._order(state, seq, stamp_ns)) is not None:
            self._reject(item, vehicle, sensor, state, Rejection(*why, seq, stamp_ns))
            return

        if state.stamp_origin_ns is None:
            state.stamp_origin_ns = stamp_ns
        state.last_seen = time.monotonic()
        stamp = (stamp_ns - state.stamp_origin_ns) * 1e-9
        tframe, ignored = detections_to_frame(decoded, stamp)
        if ignored:
            m.boxes_ignored.inc(ignored)
        try:
            tracks = state.tracker.step(tframe)
        except Exception as e:
            log.error("tracker_failed", exc=True, vehicle=vehicle, sensor=sensor, seq=seq)
            self._reject(
                item,
                vehicle,
                sensor,
                state,
                Rejection(ErrorReason.INTERNAL_ERROR, None, f"tracker: {e}"[:300], seq, stamp_ns),
            )
            return
        t2 = time.perf_counter()
        m.stage.labels(stage="track").observe(t2 - t1)

        wire = tracks_to_wire(tracks, state.id_base, ctx.classes)
        if state.tracks_pub is None:
            state.tracks_pub = ctx.session.declare_publisher(
                ctx.keys.tracks(vehicle, sensor),
                encoding=MSGPACK,
                congestion_control=ctx.congestion,
            )
        payload = encode_track_frame(
            vehicle=vehicle,
            sensor=sensor,
            seq=seq,
            stamp_ns=stamp_ns,
            frame_id=ctx.settings.world_frame_id if decoded.pose is not None else frame.frame_id,
            pose=frame.pose,
            key_frame=frame.key_frame,
            instance=ctx.settings.instance,
            received_ns=item.received_ns,
            published_ns=time.time_ns(),
            tracks=wire,
        )
        state.tracks_pub.put(payload)
        now_ns = time.time_ns()
        t3 = time.perf_counter()
        m.stage.labels(stage="publish").observe(t3 - t2)
        m.end_to_end.observe(max(0.0, (now_ns - stamp_ns) * 1e-9))
        m.service_latency.observe((now_ns - item.received_ns) * 1e-9)
        m.count_tracked(vehicle)
        m.active_tracks.inc(len(wire) - state.active_tracks)
        state.active_tracks = len(wire)
        state.last_seq, state.last_stamp_ns = seq, stamp_ns
        state.frames += 1
        state.dirty = True
        log.debug(
            "frame_tracked",
            vehicle=vehicle,
            sensor=sensor,
            seq=seq,
            boxes=len(decoded.boxes),
            tracks=len(wire),
            ms=round((t3 - t0) * 1e3, 3),
        )

    def _order(
        self, s: SensorState, seq: int, stamp_ns: int
    ) -> tuple[ErrorReason, str, str] | None:
        """Reject reason for a frame out of order, or None (possibly after a reset)."""
        if s.last_seq is None or s.last_stamp_ns is None:
            return None
        cfg = self.ctx.settings
        if seq == s.last_seq:
            return ErrorReason.DUPLICATE_SEQ, "seq", f"seq {seq} was already processed"
        behind = s.last_stamp_ns - stamp_ns
        if behind > cfg.reset_backward_s * 1e9:
            self._reset(s, "time_backwards", seq, stamp_ns)
            return None
        if behind >= 0:
            return (
                ErrorReason.OUT_OF_ORDER,
                "stamp_ns",
                f"stamp_ns {stamp_ns} is not after the last processed {s.last_stamp_ns}",
            )
        if seq < s.last_seq:
            return (
                ErrorReason.SEQ_NOT_INCREASING,
                "seq",
                f"seq {seq} is below the last processed {s.last_seq}",
            )
        if -behind > cfg.reset_gap_s * 1e9:
            self._reset(s, "gap", seq, stamp_ns)
        return None

    def _reset(self, s: SensorState, reason: str, seq: int, stamp_ns: int) -> None:
        gap_s = (stamp_ns - (s.last_stamp_ns or stamp_ns)) * 1e-9
        s.reset(stamp_ns)
        s.last_seq = s.last_stamp_ns = None
        self.ctx.metrics.resets.labels(reason=reason).inc()
        self.ctx.metrics.active_tracks.dec(s.active_tracks)
        s.active_tracks = 0
        log.warning(
            "tracker_reset",
            vehicle=s.vehicle,
            sensor=s.sensor,
            seq=seq,
            reason=reason,
            jump_s=round(gap_s, 3),
            id_base=s.id_base,
        )

    # ------------------------------------------------------------------ refusals
    def _reject(
        self,
        item: Inbound,
        vehicle: str,
        sensor: str,
        state: SensorState | None,
        r: Rejection,
        counted: bool = False,
    ) -> None:
        ctx = self.ctx
        if not counted:
            ctx.metrics.count_error(r.reason, vehicle)
        err = FrameError(
            schema_version=SCHEMA_VERSION,
            vehicle=vehicle,
            sensor=sensor,
            seq=r.seq,
            stamp_ns=r.stamp_ns,
            reason=r.reason,
            field=None if r.field is None else r.field[:256],
            detail=r.detail[:1024],
            instance=ctx.settings.instance,
            received_ns=item.received_ns,
        )
        payload = encode_message(err)
        try:
            if state is not None:
                if state.errors_pub is None:
                    state.errors_pub = ctx.session.declare_publisher(
                        ctx.keys.errors(vehicle, sensor),
                        encoding=MSGPACK,
                        congestion_control=ctx.congestion,
                    )
                state.errors_pub.put(payload)
            else:
                ctx.put(ctx.keys.errors(vehicle, sensor), payload)
        except zenoh.ZError as e:
            log.error(
                "error_publish_failed", vehicle=vehicle, sensor=sensor, seq=r.seq, error=str(e)
            )
        log.warning(
            "frame_dropped" if r.reason.value.startswith("dropped") else "frame_rejected",
            vehicle=vehicle,
            sensor=sensor,
            seq=r.seq,
            reason=r.reason.value,
            field=r.field,
            detail=r.detail,
        )

    def _drop(self, item: Inbound, reason: ErrorReason, counted: bool = False) -> None:
        """Report a frame shed under load (its header is read, nothing else)."""
        vehicle, sensor = self.ctx.keys.sensor_of(item.key) or ("", "")
        if not (NAME_RE.match(vehicle) and NAME_RE.match(sensor)):
            if not counted:
                self.ctx.metrics.count_error(reason, "")
            return
        seq, stamp_ns = peek_header(item.payload)
        detail = {
            ErrorReason.DROPPED_QUEUE_FULL: "worker queue full (backpressure drop_oldest)",
            ErrorReason.DROPPED_SHUTDOWN: "service shutting down",
        }.get(reason, reason.value)
        self._reject(
            item,
            vehicle,
            sensor,
            self.sensors.get(f"{vehicle}/{sensor}"),
            Rejection(reason, None, detail, seq, stamp_ns),
            counted=counted,
        )


def peek_header(payload: bytes) -> tuple[int | None, int | None]:
    """seq and stamp_ns of a payload, if it is readable enough (for drop notices)."""
    r = decode_detection_frame(payload)
    if isinstance(r, Rejection):
        return r.seq, r.stamp_ns
    return r.frame.seq, r.frame.stamp_ns
