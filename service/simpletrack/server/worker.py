"""Tracker workers: each owns a queue and the sensors hashed to it, and runs, per frame,
decode → ordering check → tracker step → publish. One thread per worker keeps a sensor's
frames strictly in order; sensors on different workers never wait for each other.
"""

from __future__ import annotations

import re
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field, replace

import zenoh

from simpletrack.core.tracker import Tracker
from simpletrack.server.finite import FloatingPointErrors, non_finite_refusal
from simpletrack.server.intake import Dropped, Inbound, WorkQueue
from simpletrack.server.logs import get_logger
from simpletrack.server.metrics import Metrics
from simpletrack.server.outbox import Outbox, congestion_control, dropped
from simpletrack.server.registry import SensorRegistry
from simpletrack.server.sensors import (
    Arrival,
    Order,
    OrderRules,
    SensorBudget,
    SensorState,
    Verdict,
    check_order,
    lead_ns,
)
from simpletrack.server.settings import ServiceSettings
from simpletrack.server.snapshots import SnapshotWriter
from simpletrack.wire.codec import (
    DecodeLimits,
    Rejection,
    decode_detection_frame,
    encode_track_frame,
)
from simpletrack.wire.columns import TrackArrays
from simpletrack.wire.convert import frame_from_wire, tracks_to_wire
from simpletrack.wire.keys import Keys
from simpletrack.wire.models import NAME_PATTERN
from simpletrack.wire.reasons import ErrorReason

log = get_logger("pool")  # the logger of these lines since before the split (docs/SERVICE.md)
NAME_RE = re.compile(NAME_PATTERN)
HOUSEKEEPING_S = 0.5


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
        return congestion_control(self.settings.congestion_control)


class Worker(threading.Thread):
    def __init__(self, index: int, queue: WorkQueue, ctx: Context) -> None:
        super().__init__(name=f"tracker-{index}", daemon=True)
        self.index, self.queue, self.ctx = index, queue, ctx
        s = ctx.settings
        self.sensors = SensorRegistry(
            budget=ctx.budget,
            metrics=ctx.metrics,
            new_tracker=ctx.new_tracker,
            digest=ctx.tracker_config_digest,
            writer=ctx.writer,
            state_dir=s.state_dir,
            reclaim_after_s=s.reset_gap_s,
        )
        self.outbox = Outbox(ctx.session, ctx.keys, ctx.congestion, s.instance)
        self.rules = OrderRules(reset_gap_s=s.reset_gap_s, reset_backward_s=s.reset_backward_s)
        self.drain_deadline: float | None = None
        self._next_snapshot = time.monotonic() + s.snapshot_interval_s
        self._next_housekeeping = time.monotonic() + HOUSEKEEPING_S

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
                    self._announce(item)
                elif item is not None:
                    item()
                if time.monotonic() >= self._next_housekeeping:
                    self._housekeeping()
            except Exception:  # never let one frame kill the thread of many sensors
                log.error("worker_error", exc=True, worker=self.index)
        self.sensors.snapshot_dirty()
        self.outbox.close()

    def _housekeeping(self) -> None:
        now = time.monotonic()
        self._next_housekeeping = now + HOUSEKEEPING_S
        gone = self.sensors.evict_idle(now, self.ctx.settings.sensor_idle_s)
        gone += self.sensors.reclaimed_now
        self.sensors.reclaimed_now = []
        for s in gone:
            self.outbox.forget(s.vehicle, s.sensor)
        if now >= self._next_snapshot:
            self._next_snapshot = now + self.ctx.settings.snapshot_interval_s
            self.sensors.snapshot_dirty()

    # ------------------------------------------------------------------ one frame
    def _process(self, item: Inbound) -> None:
        ctx, m = self.ctx, self.ctx.metrics
        t0 = time.perf_counter()
        m.stage.labels(stage="queue").observe(t0 - item.received_at)
        vehicle, sensor = ctx.keys.sensor_of(item.key) or ("", "")
        if not (NAME_RE.fullmatch(vehicle) and NAME_RE.fullmatch(sensor)):
            # No errors key can be derived from a key like this: count and log only.
            m.count_error(ErrorReason.INVALID_VALUE, "")
            log.warning("frame_rejected", key=item.key, reason="invalid_value", field="key")
            return
        state = self.sensors.get(f"{vehicle}/{sensor}")

        decoded = decode_detection_frame(item.payload, ctx.limits, ctx.class_codes)
        t1 = time.perf_counter()
        m.stage.labels(stage="decode").observe(t1 - t0)
        if isinstance(decoded, Rejection):
            self._refuse(item, vehicle, sensor, state, decoded)
            return
        frame = decoded.frame
        seq, stamp_ns = frame.seq, frame.stamp_ns
        if frame.vehicle != vehicle or frame.sensor != sensor:
            field_name = "vehicle" if frame.vehicle != vehicle else "sensor"
            detail = f"payload says {frame.vehicle}/{frame.sensor}, key says {vehicle}/{sensor}"
            r = Rejection(ErrorReason.KEY_MISMATCH, field_name, detail, seq, stamp_ns)
            self._refuse(item, vehicle, sensor, state, r)
            return

        arrival = Arrival(seq, stamp_ns, item.received_ns, frame.session_id)
        bridged = False
        if state is None:
            state = self.sensors.add(vehicle, sensor, seq)
            if state is None:
                detail = (
                    f"already tracking max_sensors={ctx.budget.limit} sensors, none of this "
                    f"worker's silent for over reset_gap_s"
                )
                r = Rejection(ErrorReason.TOO_MANY_SENSORS, None, detail, seq, stamp_ns)
                self._refuse(item, vehicle, sensor, None, r)
                return
        else:
            verdict = check_order(state.last, arrival, self.rules, state.before)
            if verdict.order is Order.UNDO_LAST:
                self._undo(state, arrival)
                verdict = check_order(state.last, arrival, self.rules)
            if verdict.reason is not None:
                r = Rejection(verdict.reason, verdict.field, verdict.detail, seq, stamp_ns)
                self._refuse(item, vehicle, sensor, state, r)
                return
            state.keep_undo()
            if verdict.order.resets:
                self._reset(state, verdict, seq, stamp_ns)
            elif verdict.order is Order.BRIDGE_GAP:
                bridged = True
                log.info(
                    "gap_bridged",
                    vehicle=vehicle,
                    sensor=sensor,
                    seq=seq,
                    gap_s=round((stamp_ns - (state.last_stamp_ns or stamp_ns)) * 1e-9, 3),
                )

        stamp = state.tracker_stamp(stamp_ns)
        state.last_seen = time.monotonic()
        tframe, ignored = frame_from_wire(decoded, stamp)
        if bridged:  # the core re-associates what the prediction over the gap missed
            tframe = replace(tframe, after_gap=True)
        if ignored:
            m.boxes_ignored.inc(ignored)
        fp = FloatingPointErrors()
        try:
            with fp:
                tracks = state.tracker.step(tframe)
        except Exception as e:
            log.error("tracker_failed", exc=True, vehicle=vehicle, sensor=sensor, seq=seq)
            state.before = None  # what keep_undo holds is no longer the state before the last
            detail = f"tracker: {e}"[:300]
            r = Rejection(ErrorReason.INTERNAL_ERROR, None, detail, seq, stamp_ns)
            self._refuse(item, vehicle, sensor, state, r)
            return
        t2 = time.perf_counter()
        m.stage.labels(stage="track").observe(t2 - t1)

        with fp:
            wire = tracks_to_wire(tracks, state.id_base, ctx.classes)
        if not self._publishable(item, state, wire, fp, seq, stamp_ns):
            return
        self.sensors.reserve_ids(state)  # durable before any of the frame's ids leaves
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
        self.outbox.tracks(vehicle, sensor, payload)
        now_ns = time.time_ns()
        t3 = time.perf_counter()
        m.stage.labels(stage="publish").observe(t3 - t2)
        m.end_to_end.observe(max(0.0, (now_ns - stamp_ns) * 1e-9))
        m.service_latency.observe((now_ns - item.received_ns) * 1e-9)
        m.count_tracked(vehicle)
        m.active_tracks.inc(state.tracked(arrival, len(wire)))
        log.debug(
            "frame_tracked",
            vehicle=vehicle,
            sensor=sensor,
            seq=seq,
            boxes=len(decoded.boxes),
            tracks=len(wire),
            ms=round((t3 - t0) * 1e3, 3),
        )

    def _undo(self, s: SensorState, frame: Arrival) -> None:
        """The last frame ran off the service's clock and this one, of the stream before
        it, agrees with it: forget the last frame rather than refuse or reset on its word."""
        undone, before = s.last, s.before
        self.ctx.metrics.active_tracks.inc(s.undo_last())
        lead = None if undone is None or before is None else lead_ns(before, undone)
        log.warning(
            "frame_undone",
            vehicle=s.vehicle,
            sensor=s.sensor,
            seq=frame.seq,
            undone_seq=None if undone is None else undone.seq,
            undone_lead_s=None if lead is None else round(lead * 1e-9, 3),
        )

    def _publishable(
        self,
        item: Inbound,
        s: SensorState,
        wire: TrackArrays,
        fp: FloatingPointErrors,
        seq: int,
        stamp_ns: int,
    ) -> bool:
        """The guard before publishing (docs/SERVICE.md, "What a fault can cost"): numpy's
        floating-point errors go to the log; a frame with NaN or inf is never published, and
        the tracker whose state produced it is reset (ids continue above the old ones)."""
        if fp.kinds:
            log.warning(
                "numeric_warning", vehicle=s.vehicle, sensor=s.sensor, seq=seq, kinds=fp.kinds
            )
        r = non_finite_refusal(wire, seq, stamp_ns)
        if r is None:
            return True
        dropped_tracks = s.active_tracks
        s.reset(stamp_ns)
        self.ctx.metrics.resets.labels(reason="non_finite").inc()
        self.ctx.metrics.active_tracks.dec(dropped_tracks)
        log.error(
            "non_finite_tracks",
            vehicle=s.vehicle,
            sensor=s.sensor,
            seq=seq,
            field=r.field,
            id_base=s.id_base,
        )
        self._refuse(item, s.vehicle, s.sensor, s, r)
        return False

    def _reset(self, s: SensorState, verdict: Verdict, seq: int, stamp_ns: int) -> None:
        reason = verdict.order.value
        gap_s = (stamp_ns - (s.last_stamp_ns or stamp_ns)) * 1e-9
        dropped_tracks = s.active_tracks
        s.reset(stamp_ns)
        self.ctx.metrics.resets.labels(reason=reason).inc()
        self.ctx.metrics.active_tracks.dec(dropped_tracks)
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
    def _refuse(
        self,
        item: Inbound,
        vehicle: str,
        sensor: str,
        state: SensorState | None,
        r: Rejection,
        counted: bool = False,
    ) -> None:
        if not counted:
            self.ctx.metrics.count_error(r.reason, vehicle)
        try:
            self.outbox.refuse(vehicle, sensor, r, item.received_ns, held=state is not None)
        except ValueError as e:  # a notice that cannot be built: counted above, never a crash
            log.warning(
                "frame_rejected", key=item.key, reason=r.reason.value, unpublished=str(e)[:200]
            )

    def _announce(self, d: Dropped) -> None:
        """One notice for frames the queue gave up (counted when they were given up)."""
        vehicle, sensor = self.ctx.keys.sensor_of(d.key) or ("", "")
        if NAME_RE.match(vehicle) and NAME_RE.match(sensor):
            held = self.sensors.get(f"{vehicle}/{sensor}") is not None
            self.outbox.drops(vehicle, sensor, d.reason, d.seqs, d.stamp_ns, d.received_ns, held)

    def _drop(self, item: Inbound, reason: ErrorReason, counted: bool = False) -> None:
        """Report a frame shed under load (its header is read, nothing else)."""
        vehicle, sensor = self.ctx.keys.sensor_of(item.key) or ("", "")
        if not (NAME_RE.fullmatch(vehicle) and NAME_RE.fullmatch(sensor)):
            if not counted:
                self.ctx.metrics.count_error(reason, "")
            return
        state = self.sensors.get(f"{vehicle}/{sensor}")
        self._refuse(item, vehicle, sensor, state, dropped(reason, item.payload), counted)
