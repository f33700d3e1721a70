"""A worker's fused vehicles (docs/SERVICE.md, "Vehicle fusion"): a frame of a fused sensor
is decoded and checked as any frame, then waits in its vehicle's reorder buffer; released
in stamp order, it is one step of the vehicle's tracker, whose tracks go out as one
``VehicleTrackFrame`` on ``<prefix>/<vehicle>/@vehicle/tracks``.

Refusals stay on the sensor's errors key: a frame is a sensor's, whatever it feeds.
"""

from __future__ import annotations

import logging
import time
from typing import TYPE_CHECKING

from simpletrack.core.vehicle import Condition, Outcome, SensorInput
from simpletrack.server.finite import FloatingPointErrors, non_finite_refusal
from simpletrack.server.intake import Inbound
from simpletrack.server.logs import get_logger
from simpletrack.server.sensors import (
    Arrival,
    Order,
    check_order,
    key_mismatch,
    lead_ns,
    unheard_start,
)
from simpletrack.server.vehicles import VehicleState, Waiting
from simpletrack.wire.codec import Rejection, decode_detection_frame
from simpletrack.wire.columns import TrackArrays
from simpletrack.wire.convert import (
    boxes_from_wire,
    detection_extents,
    pack_vehicle_tracks_checked,
    vehicle_tracks_to_wire,
)
from simpletrack.wire.keys import VEHICLE_STREAM
from simpletrack.wire.reasons import ErrorReason
from simpletrack.wire.vehicle_tracks import encode_vehicle_track_frame

if TYPE_CHECKING:
    from simpletrack.server.worker import Worker

log = get_logger("pool")
WORLD, VEHICLE = "world", "vehicle"


class FusedFrames:
    def __init__(self, worker: Worker) -> None:
        self.w = worker
        self._waiting: set[str] = set()  # vehicles with frames in their buffer

    # ------------------------------------------------------------------ a frame in
    def track(self, item: Inbound, vehicle: str, sensor: str, replayed: bool = False) -> None:
        w, ctx, m = self.w, self.w.ctx, self.w.ctx.metrics
        t0 = time.perf_counter()
        m.stages["queue"].observe(t0 - item.received_at)
        key = f"{vehicle}/{VEHICLE_STREAM}"
        got = w.sensors.get(key)
        state = got if isinstance(got, VehicleState) else None
        decoded = decode_detection_frame(
            item.payload, ctx.limits, ctx.class_codes, detection_extents
        )
        m.stages["decode"].observe(time.perf_counter() - t0)
        if isinstance(decoded, Rejection):
            w._refuse(item, vehicle, sensor, decoded)
            return
        frame = decoded.frame
        seq, stamp_ns = frame.seq, frame.stamp_ns
        mismatch = key_mismatch(frame, vehicle, sensor)
        if mismatch is not None:
            w._refuse(item, vehicle, sensor, mismatch)
            return
        kind = WORLD if decoded.pose is not None else VEHICLE
        transform = decoded.pose if decoded.pose is not None else decoded.extrinsic
        if transform is None or (state is not None and state.frame not in (None, kind)):
            w._refuse(item, vehicle, sensor, _no_transform(state, seq, stamp_ns))
            return
        flagged = not w._quiet and w._plausible(vehicle, sensor, seq, decoded, item)
        if state is None:
            added = w.sensors.add(vehicle, VEHICLE_STREAM, seq)
            if not isinstance(added, VehicleState):
                detail = f"already tracking max_sensors={ctx.budget.limit} streams"
                w._refuse(item, vehicle, sensor, Rejection(
                    ErrorReason.TOO_MANY_SENSORS, None, detail, seq, stamp_ns))  # fmt: skip
                return
            state = added
        state.frame = kind
        if flagged:
            state.implausible += 1
        arrival = Arrival(seq, stamp_ns, item.received_ns, frame.session_id)
        if replayed and state.covers(item):
            return  # in the state taken over already
        last = state.arrivals.get(sensor)
        if (
            item is w.live
            and last is not None
            and unheard_start(last, arrival)
            and w.refill(key, item, last, arrival, state)
        ):
            return
        verdict = check_order(last, arrival, w.rules)
        if verdict.reason is not None:
            w._refuse(item, vehicle, sensor, Rejection(
                verdict.reason, verdict.field, verdict.detail, seq, stamp_ns))  # fmt: skip
            return
        state.arrivals[sensor] = arrival
        state.last_seen = time.monotonic()
        if not replayed:
            state.heard(sensor, arrival)
        if ctx.per_sensor_output:
            w._per_sensor(state, sensor, item, decoded, arrival)
        waiting = Waiting(item, sensor, decoded, arrival, transform, replayed or w._quiet)
        state.buffer.push(sensor, seq, stamp_ns, waiting, time.monotonic())
        self._waiting.add(key)
        self.release(state)

    # ------------------------------------------------------------------ frames out
    def release(self, state: VehicleState, flush: bool = False) -> None:
        """Apply what the vehicle's buffer lets go now (everything: ``flush``)."""
        now = time.monotonic()
        ready = state.buffer.flush() if flush else state.buffer.pop_ready(now)
        wait = self.w.ctx.metrics.fusion_wait
        if ready:
            # The sensors' standing before the frames are judged: a reference silent since
            # before them (a vehicle's link down for seconds) is no clock to check them by.
            state.standing(now)
        for waiting in ready:
            wait.observe(now - waiting.item.received_at)
            with self.w.ctx.trackers.tracking(self.w.index):
                self._apply(state, waiting)
        if ready:  # and after, for the next frames' wait and the messages
            state.standing(now)
        if not len(state.buffer):
            self._waiting.discard(f"{state.vehicle}/{VEHICLE_STREAM}")

    def forget(self, stream: str) -> None:
        """The vehicle left this worker without its waiting frames applied (a fence)."""
        self._waiting.discard(stream)

    def release_due(self) -> float | None:
        """Release the vehicles whose first waiting frame's window is over (a frame of a
        vehicle goes at once when its sensors pass it: ``track`` releases then); returns when
        the next one is due (None: nothing waits)."""
        now = time.monotonic()
        nxt: float | None = None
        for key in list(self._waiting):
            state = self.w.sensors.get(key)
            if not isinstance(state, VehicleState):
                self._waiting.discard(key)
                continue
            due = state.buffer.due()
            if due is None or due <= now:
                self.release(state)  # an empty buffer: only leaves the waiting set
                due = state.buffer.due()
            if due is not None:
                nxt = due if nxt is None else min(nxt, due)
        return nxt

    def flush_all(self) -> None:
        for key in list(self._waiting):
            state = self.w.sensors.get(key)
            if isinstance(state, VehicleState):
                self.release(state, flush=True)
        self._waiting.clear()

    def _apply(self, state: VehicleState, waiting: Waiting) -> None:
        w, ctx, m = self.w, self.w.ctx, self.w.ctx.metrics
        item, sensor, arrival = waiting.item, waiting.sensor, waiting.arrival
        t1 = time.perf_counter()
        after_gap = self._gap(state, arrival)
        boxes = boxes_from_wire(waiting.decoded.boxes, waiting.decoded.codes)
        ignored = len(waiting.decoded.boxes) - len(boxes)
        if ignored:
            m.boxes_ignored.inc(ignored)
        received = arrival.received_ns
        lead = (
            None if waiting.replayed or received is None else (arrival.stamp_ns - received) * 1e-9
        )
        inp = SensorInput(
            sensor=sensor,
            seq=arrival.seq,
            stamp_ns=arrival.stamp_ns,
            boxes=boxes,
            transform=waiting.transform,
            key_frame=waiting.decoded.frame.key_frame,
            lead_s=lead,
            after_gap=after_gap,
        )
        before = state.tracker.records[sensor].condition
        fp = FloatingPointErrors()
        try:
            with fp:
                result = state.tracker.apply(inp)
        except Exception as e:
            log.error("tracker_failed", exc=True, vehicle=state.vehicle, sensor=sensor,
                      seq=arrival.seq)  # fmt: skip
            detail = f"tracker: {e}"[:300]
            w._refuse(item, state.vehicle, sensor, Rejection(
                ErrorReason.INTERNAL_ERROR, None, detail, arrival.seq, arrival.stamp_ns))  # fmt: skip
            return
        if fp.kinds:  # numpy's floating-point errors as events, as for a sensor's step
            log.warning("numeric_warning", vehicle=state.vehicle, sensor=sensor,
                        seq=arrival.seq, kinds=fp.kinds)  # fmt: skip
        m.fusion_frames.labels(outcome=result.outcome.value).inc()
        state.taken[sensor] = arrival
        self._log_condition(state, sensor, before)
        t2 = time.perf_counter()
        m.stages["track"].observe(t2 - t1)
        if result.outcome is Outcome.LATE:
            w._refuse(item, state.vehicle, sensor, Rejection(
                ErrorReason.LATE, "stamp_ns", result.detail, arrival.seq, arrival.stamp_ns))  # fmt: skip
            return
        if result.outcome is Outcome.FLAGGED:
            w._refuse(item, state.vehicle, sensor, Rejection(
                ErrorReason.SENSOR_FLAGGED, None, result.detail, arrival.seq, arrival.stamp_ns))  # fmt: skip
            return
        state.dirty = True
        if result.tracks is None:
            return  # watched (verification) or re-processed: no message of its own
        vt = result.tracks
        state.last = arrival
        # The message's tracks map packed in one compiled call with the finite guard's look
        # (server/worker.py does the same for a sensor's); None: the columns' way, whose
        # guard names a NaN or inf.
        tracks: TrackArrays | bytes | None = pack_vehicle_tracks_checked(
            vt.tracks, vt.existence, vt.sensor_stamp_ns, ctx.classes, len(state.tracker.sensors)
        )
        refusal = None
        if tracks is None:
            tracks = vehicle_tracks_to_wire(
                vt.tracks, vt.existence, vt.sensor_stamp_ns, ctx.classes
            )
            refusal = non_finite_refusal(tracks, arrival.seq, arrival.stamp_ns)
        if refusal is not None:  # never published: subscribers' decoders refuse NaN and inf
            log.error("non_finite_tracks", vehicle=state.vehicle, sensor=sensor,
                      seq=arrival.seq, field=refusal.field)  # fmt: skip
            self._reset(state, "non_finite")
            w._refuse(item, state.vehicle, sensor, refusal)
            return
        w.sensors.reserve_ids(state)
        quiet = waiting.replayed and (
            state.published_seq is not None and vt.seq <= state.published_seq
        )
        frame = waiting.decoded.frame
        conditions = [
            c.value for c in (state.tracker.records[s].condition for s in state.tracker.sensors)
        ]
        payload = encode_vehicle_track_frame(
            vehicle=state.vehicle,
            seq=vt.seq,
            stamp_ns=vt.stamp_ns,
            sensor=sensor,
            sensor_seq=arrival.seq,
            frame_id=ctx.settings.world_frame_id if state.frame == WORLD else ctx.vehicle_frame_id,
            pose=frame.pose,
            instance=ctx.settings.instance,
            received_ns=item.received_ns,
            published_ns=time.time_ns(),
            sensors=list(state.tracker.sensors),
            sensor_state=conditions,
            tracks=tracks,
            epoch=state.epoch,
        )
        if not quiet:
            w.outbox.vehicle_tracks(state.vehicle, payload)
        now_ns = time.time_ns()
        t3 = time.perf_counter()
        m.stages["publish"].observe(t3 - t2)
        m.observe_end_to_end(arrival.stamp_ns, item.received_ns, now_ns, state.vehicle)
        m.service_latency.observe((now_ns - item.received_ns) * 1e-9)
        m.count_tracked(state.vehicle)
        n_tracks = len(vt.tracks.ids)
        m.active_tracks.inc(state.tracked(n_tracks))
        if log.enabled(logging.DEBUG):
            log.debug("vehicle_tracked", vehicle=state.vehicle, sensor=sensor, seq=vt.seq,
                      tracks=n_tracks, ms=round((t3 - t1) * 1e3, 3))  # fmt: skip

    def _gap(self, state: VehicleState, arrival: Arrival) -> bool:
        """The vehicle's gap rule (every sensor silent over reset_gap_s): bridged when the
        service's clock saw the same gap (an outage), else the tracks start afresh."""
        last = state.last
        gap = self.w.rules.reset_gap_s * 1e9
        if last is None or arrival.stamp_ns - last.stamp_ns <= gap:
            return False
        lead = lead_ns(last, arrival)
        if lead is not None and lead <= gap:
            return True
        self._reset(state, Order.RESET_GAP.value)
        log.warning("tracker_reset", vehicle=state.vehicle, sensor=VEHICLE_STREAM,
                    seq=arrival.seq, reason=Order.RESET_GAP.value,
                    jump_s=round((arrival.stamp_ns - last.stamp_ns) * 1e-9, 3))  # fmt: skip
        return False

    def _reset(self, state: VehicleState, reason: str) -> None:
        """The vehicle's tracks dropped (ids continue above the old ones), counted."""
        dropped = state.active_tracks
        state.tracker.reset()
        state.resets += 1
        state.active_tracks = 0
        self.w.ctx.metrics.active_tracks.dec(dropped)
        self.w.ctx.metrics.resets.labels(reason=reason).inc()

    def _log_condition(self, state: VehicleState, sensor: str, before: Condition) -> None:
        rec = state.tracker.records[sensor]
        if rec.condition is before:
            return
        bad = rec.condition in (Condition.CLOCK, Condition.EXTRINSIC)
        (log.warning if bad else log.info)(
            "sensor_condition", vehicle=state.vehicle, sensor=sensor,
            condition=rec.condition.value, was=before.value, detail=rec.detail or None,
        )  # fmt: skip


def _no_transform(state: VehicleState | None, seq: int, stamp_ns: int) -> Rejection:
    if state is not None and state.frame == WORLD:
        detail = (
            "this vehicle's fused frames carry poses (it tracks in the world frame): "
            "every fused sensor must send its sensor->world pose"
        )
    elif state is not None and state.frame == VEHICLE:
        detail = (
            "this vehicle's fused frames carry extrinsics (it tracks in the vehicle frame): "
            "every fused sensor must send its sensor->vehicle extrinsic, not a pose"
        )
    else:
        detail = (
            "a fused sensor's frame needs its sensor->world pose, or its sensor->vehicle "
            "extrinsic when the vehicle has no poses"
        )
    return Rejection(ErrorReason.MISSING_FIELD, "pose", detail, seq, stamp_ns)


__all__ = ["FusedFrames"]
