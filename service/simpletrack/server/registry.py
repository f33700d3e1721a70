"""The sensors one worker holds: admission under the global budget, restore from snapshots,
eviction of idle sensors (their ids stay reserved), the snapshots and id reservations
written to disk.

Admission at capacity: while every ``max_sensors`` slot is taken, a sensor silent for over
``reclaim_after_s`` (the service's ``reset_gap_s``: its next frame would start a fresh tracker
anyway) gives way, the longest silent first: at once to a new sensor of the same worker, and
at the next housekeeping on every other worker. A sensor that keeps sending is never evicted.

Mutated only on the worker's thread; ``status`` and ``names`` may be read from any thread.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from enum import Enum
from pathlib import Path

from simpletrack.core.tracker import STATE_FORMAT, Tracker
from simpletrack.server.logs import get_logger
from simpletrack.server.metrics import Metrics
from simpletrack.server.sensors import Arrival, SensorBudget, SensorState
from simpletrack.server.snapshots import (
    ID_BLOCK,
    Batch,
    SnapshotWriter,
    encode_ids,
    ids_path,
    read_ids,
    snapshot_path,
    write_atomic,
)
from simpletrack.server.vehicles import VehicleState
from simpletrack.wire.codec import encode as encode_message
from simpletrack.wire.keys import VEHICLE_STREAM
from simpletrack.wire.models import SensorSnapshot, SensorStatus

Stream = SensorState | VehicleState

log = get_logger("pool")  # the logger of these lines since before the split (docs/SERVICE.md)
MAX_RETIRED = 100_000  # id reservations of evicted sensors kept in memory


class Departure(Enum):
    """Why a sensor leaves the registry; the value is its log event."""

    EVICTED = "sensor_evicted"  # silent for over sensor_idle_s
    RECLAIMED = "sensor_reclaimed"  # silent for over reset_gap_s while the slots are full
    RELEASED = "sensor_released"  # handed to another member of the group


class SensorRegistry:
    def __init__(
        self,
        budget: SensorBudget,
        metrics: Metrics,
        new_tracker: Callable[[], Tracker],
        digest: str,
        writer: SnapshotWriter | None,
        state_dir: Path | None,
        reclaim_after_s: float = math.inf,
        new_vehicle: Callable[[str, int], VehicleState] | None = None,
        vehicle_of: Callable[[SensorSnapshot], VehicleState] | None = None,
        vehicle_digest: str = "",
        state_format: int = STATE_FORMAT,
    ) -> None:
        """``new_vehicle(vehicle, id_floor)`` and ``vehicle_of(snapshot)`` make the fused
        vehicles' states (server/vehicles.py); ``vehicle_digest`` is what their snapshots
        must carry to be restored; ``state_format`` the trackers' byte form in the states it
        writes (``core.tracker.STATE_FORMATS``)."""
        self.budget, self.metrics, self.new_tracker, self.digest = (
            budget,
            metrics,
            new_tracker,
            digest,
        )
        self.writer, self.state_dir = writer, state_dir
        self.reclaim_after_s = reclaim_after_s
        self.new_vehicle, self.vehicle_of = new_vehicle, vehicle_of
        self.vehicle_digest = vehicle_digest
        self.state_format = state_format
        self.sensors: dict[str, Stream] = {}
        self.retired: dict[str, int] = {}  # evicted sensor -> lowest unused id
        # stream -> the custody epoch a takeover gave it, for the state ``add`` creates
        self.epochs: dict[str, int] = {}
        # sensor -> its id floor on disk (every id it published is below); absent: read it
        self.id_floor: dict[str, int] = {}
        self.snapshot_done_at = time.monotonic()
        # Sensors evicted by ``add`` to make room: the worker undeclares their publishers.
        self.reclaimed_now: list[Stream] = []

    def __len__(self) -> int:
        return len(self.sensors)

    def get(self, key: str) -> Stream | None:
        return self.sensors.get(key)

    def sensor(self, key: str) -> SensorState | None:
        """A sensor's own stream (None for a vehicle's or none)."""
        s = self.sensors.get(key)
        return s if isinstance(s, SensorState) else None

    # ------------------------------------------------------------------ admission
    def add(self, vehicle: str, sensor: str, seq: int) -> Stream | None:
        """A new stream (a sensor, or a fused vehicle: ``sensor`` ``@vehicle``), or None
        when the budget is spent. Its ids continue above any it published before an
        eviction. At capacity, this worker's longest silent stream gives way if it has been
        silent for over ``reclaim_after_s``."""
        if not self.budget.acquire() and not (self._reclaim_one() and self.budget.acquire()):
            return None
        key = f"{vehicle}/{sensor}"
        floor = self.retired.pop(key, 0)
        state: Stream
        if sensor == VEHICLE_STREAM:
            assert self.new_vehicle is not None, "a vehicle stream without fusion settings"
            state = self.new_vehicle(vehicle, floor)
        else:
            state = SensorState(vehicle, sensor, self.new_tracker(), id_base=floor)
        state.epoch = self.epochs.pop(key, state.epoch)
        self.sensors[key] = state
        self.metrics.active_sensors.inc()
        log.info("sensor_added", vehicle=vehicle, sensor=sensor, seq=seq, id_base=state.id_base)
        return state

    # ------------------------------------------------------------------ restore
    def restore_floor(self, vehicle: str, sensor: str, floor: int) -> None:
        """A sensor's id reservation from the state directory (before ``adopt`` and before
        the worker starts): whatever becomes of its snapshot, its ids continue above it."""
        key = f"{vehicle}/{sensor}"
        self.id_floor[key] = floor
        self.retired[key] = max(self.retired.get(key, 0), floor)

    def adopt(self, snap: SensorSnapshot, use_floor: bool = True) -> Stream | None:
        """Take over a stream from a snapshot: the state directory's (before the worker
        starts, or at a takeover when no member has it) or another member's (a hand-off or
        a checkpoint: ``use_floor`` False, its ids are exact, this disk's floor is older)."""
        key = f"{snap.vehicle}/{snap.sensor}"
        floor = max(snap.id_next, self.id_floor.get(key, 0)) if use_floor else snap.id_next
        if snap.tracker is None:
            self.retired[key] = max(self.retired.get(key, 0), floor)
            return None
        if snap.sensor == VEHICLE_STREAM:
            return self._adopt_vehicle(snap, key, floor, use_floor)
        tracker: Tracker | None = None
        id_base = snap.id_base
        if snap.config_digest != self.digest:
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
            tracker, id_base = self.new_tracker(), floor
        else:
            # A snapshot older than the reservation (SIGKILL after it was taken) keeps its
            # tracks and their ids; ids born since it may have been published: skip them.
            tracker.next_id = max(tracker.next_id, floor - id_base)
        if not self.budget.acquire():
            log.error("snapshot_over_max_sensors", vehicle=snap.vehicle, sensor=snap.sensor)
            self.retired[key] = floor
            return None
        state = self.sensors[key] = SensorState(
            vehicle=snap.vehicle,
            sensor=snap.sensor,
            tracker=tracker,
            id_base=id_base,
            last=_last_of(snap),
            stamp_origin_ns=snap.stamp_origin_ns,
            frames=snap.frames,
            dirty=False,
        )
        if use_floor:
            self.metrics.restored.inc()
        self.metrics.active_sensors.inc()
        log.info(
            "sensor_restored",
            vehicle=snap.vehicle,
            sensor=snap.sensor,
            seq=snap.last_seq,
            id_next=snap.id_next,
            id_floor=floor,
        )
        return state

    def _adopt_vehicle(
        self, snap: SensorSnapshot, key: str, floor: int, use_floor: bool
    ) -> VehicleState | None:
        state: VehicleState | None = None
        if snap.config_digest != self.vehicle_digest or self.vehicle_of is None:
            log.warning("snapshot_config_changed", vehicle=snap.vehicle, sensor=snap.sensor)
        else:
            try:
                state = self.vehicle_of(snap)
            except Exception:
                log.error(
                    "snapshot_tracker_unreadable", exc=True, vehicle=snap.vehicle,
                    sensor=snap.sensor,
                )  # fmt: skip
        if state is None:  # start afresh, but never reuse an id
            if self.new_vehicle is None:
                self.retired[key] = max(self.retired.get(key, 0), floor)
                return None
            state = self.new_vehicle(snap.vehicle, floor)
        else:
            state.tracker.next_id = max(state.tracker.next_id, floor)
        if not self.budget.acquire():
            log.error("snapshot_over_max_sensors", vehicle=snap.vehicle, sensor=snap.sensor)
            self.retired[key] = floor
            return None
        self.sensors[key] = state
        if use_floor:
            self.metrics.restored.inc()
        self.metrics.active_sensors.inc()
        log.info(
            "sensor_restored", vehicle=snap.vehicle, sensor=snap.sensor, seq=snap.last_seq,
            id_next=snap.id_next, id_floor=floor,
        )  # fmt: skip
        return state

    def release(self, key: str) -> None:
        """The sensor now belongs to another member: forget it here (its ids, as far as
        this member took them, stay retired: a fresh start here continues above them)."""
        s = self.sensors.get(key)
        if s is not None:
            self._evict(key, s, Departure.RELEASED)

    # ------------------------------------------------------------------ id reservations
    def reserve_ids(self, s: Stream) -> None:
        """Before a frame is published: its ids (all below ``s.id_next``) must be below the
        reservation on disk; if not, reserve the next block and wait for it to be durable."""
        if self.state_dir is None:
            return
        key = f"{s.vehicle}/{s.sensor}"
        floor = self.id_floor.get(key)
        if floor is None:  # a new sensor, or one forgotten: the disk knows
            floor = read_ids(self.state_dir, s.vehicle, s.sensor) or 0
            self.id_floor[key] = floor
            while len(self.id_floor) > MAX_RETIRED:
                del self.id_floor[next(iter(self.id_floor))]
        if s.id_next <= floor:
            return
        floor = s.id_next + ID_BLOCK
        try:
            path = ids_path(self.state_dir, s.vehicle, s.sensor)
            write_atomic(path, encode_ids(s.vehicle, s.sensor, floor))
        except OSError as e:
            # Publishing anyway: a frame answered beats a frame refused for want of disk; the
            # ids stay unique unless the process also dies and its snapshot is lost.
            self.metrics.snapshot_failures.inc()
            log.error("id_reservation_failed", vehicle=s.vehicle, sensor=s.sensor, error=str(e))
            return
        self.id_floor[key] = floor

    def release_ids(self) -> None:
        """At a clean stop, once no frame will be published: lower each reservation to the
        exact next id, so that a restart from the final snapshots gives the same ids as an
        uninterrupted run. Written after the final snapshots, by the same writer thread."""
        if self.writer is None or self.state_dir is None:
            return
        exact = {**self.retired, **{k: s.id_next for k, s in self.sensors.items()}}
        files = []
        for key, floor in self.id_floor.items():
            if key in exact and exact[key] < floor:
                vehicle, sensor = key.split("/")
                path = ids_path(self.state_dir, vehicle, sensor)
                files.append((path, encode_ids(vehicle, sensor, exact[key])))
        if files:
            self.writer.submit(Batch(files, lambda written, failed: None))

    # ------------------------------------------------------------------ eviction
    def evict_idle(self, now: float, idle_s: float) -> list[Stream]:
        """Drop the sensors silent for over ``idle_s`` (over ``reclaim_after_s`` while every
        slot of the budget is taken); their id reservation is written."""
        full = self.budget.used >= self.budget.limit
        limit = min(idle_s, self.reclaim_after_s) if full else idle_s
        gone = [(k, s) for k, s in list(self.sensors.items()) if now - s.last_seen > limit]
        for key, s in gone:
            quiet_only = now - s.last_seen <= idle_s  # gone early because slots are full
            self._evict(key, s, Departure.RECLAIMED if quiet_only else Departure.EVICTED)
        return [s for _, s in gone]

    def _reclaim_one(self) -> bool:
        """Evict the longest silent sensor if silent for over ``reclaim_after_s``."""
        if not self.sensors:
            return False
        now = time.monotonic()
        key, s = min(self.sensors.items(), key=lambda kv: kv[1].last_seen)
        if now - s.last_seen <= self.reclaim_after_s:
            return False
        self._evict(key, s, Departure.RECLAIMED)
        self.reclaimed_now.append(s)
        return True

    def _evict(self, key: str, s: Stream, why: Departure) -> None:
        del self.sensors[key]
        self.retired[key] = s.id_next
        while len(self.retired) > MAX_RETIRED:
            del self.retired[next(iter(self.retired))]
        self.budget.release()
        m = self.metrics
        if why is Departure.EVICTED:
            m.evicted.inc()
        elif why is Departure.RECLAIMED:
            m.reclaimed.inc()
        m.active_sensors.dec()
        m.active_tracks.dec(s.active_tracks)
        log.info(
            why.value,
            vehicle=s.vehicle,
            sensor=s.sensor,
            seq=s.last_seq,
            id_next=s.id_next,
        )
        self._write([(s, False)])

    # ------------------------------------------------------------------ snapshots
    def snapshot_dirty(self) -> None:
        """Snapshot every sensor changed since its last snapshot."""
        dirty = [s for s in self.sensors.values() if s.dirty]
        if dirty:
            self._write([(s, True) for s in dirty])
        else:
            self.snapshot_done_at = time.monotonic()

    def _write(self, items: list[tuple[Stream, bool]]) -> None:
        if self.writer is None or self.state_dir is None:
            return
        files = []
        for s, with_tracker in items:
            snap = self.state_of(s, with_tracker)
            files.append((snapshot_path(self.state_dir, s.vehicle, s.sensor), encode_message(snap)))
            s.dirty = False
        metrics = self.metrics

        def done(written: int, failed: int) -> None:
            metrics.snapshots.inc(written)
            if failed:
                metrics.snapshot_failures.inc(failed)
            else:
                self.snapshot_done_at = time.monotonic()

        self.writer.submit(Batch(files, done))

    def snapshot_of(self, vehicle: str, sensor: str) -> SensorSnapshot | None:
        """Only from the worker's thread (it owns the trackers): via ``queue.put_control``."""
        s = self.sensors.get(f"{vehicle}/{sensor}")
        return None if s is None else self.state_of(s)

    def state_of(self, s: Stream, with_tracker: bool = True) -> SensorSnapshot:
        """A held stream's state as this member writes it (checkpoints, hand-offs, disk)."""
        return s.snapshot(self.digest, with_tracker, state_format=self.state_format)

    # ------------------------------------------------------------------ status
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
                rate_hz=round(s.rate_hz(now), 2),
                resets=s.resets,
                implausible_frames=s.implausible,
            )
            for s in list(self.sensors.values())
            if isinstance(s, SensorState)
        ]

    def vehicles(self) -> list[VehicleState]:
        return [s for s in list(self.sensors.values()) if isinstance(s, VehicleState)]

    def names(self) -> list[tuple[str, str]]:
        return [(s.vehicle, s.sensor) for s in list(self.sensors.values())]


def _last_of(snap: SensorSnapshot) -> Arrival | None:
    """The last frame a snapshot saw. A snapshot of before ``last_received_ns`` gives its
    writing time instead: later than the receipt by at most a snapshot interval, so a clock
    jump smaller than that may then be taken for an outage."""
    if snap.last_seq is None or snap.last_stamp_ns is None:
        return None
    received = snap.last_received_ns if snap.last_received_ns is not None else snap.written_ns
    return Arrival(snap.last_seq, snap.last_stamp_ns, received, snap.last_session_id)
