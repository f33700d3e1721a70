"""A fused vehicle as a worker holds it: its tracker, its reorder buffer, each sensor's last
frame, and (with ``fusion.per_sensor_output``) each sensor's own tracker, all one stream
``<vehicle>/@vehicle`` (server/streams.py): snapshotted, checkpointed, handed off and taken
over whole, under the same rules as a sensor (docs/SCALE.md).

``VehicleState`` answers what the registry and the custody code ask of a sensor's state
(``SensorState``), plus ``covers`` and ``holes`` per sensor.
"""

from __future__ import annotations

import hashlib
import time
from collections import deque
from collections.abc import Iterable
from dataclasses import dataclass, field
from typing import Any

import msgpack
import numpy as np
import numpy.typing as npt

from simpletrack.core.config import TrackerConfig
from simpletrack.core.fusion_config import FusionConfig
from simpletrack.core.reorder import ReorderBuffer
from simpletrack.core.vehicle import Condition, VehicleTracker
from simpletrack.server.checkpoint_rule import CheckpointMark
from simpletrack.server.intake import Inbound
from simpletrack.server.sensors import RATE_FRAMES, RATE_WINDOW_S, Arrival, SensorState
from simpletrack.wire.codec import DecodedDetections, DecodeLimits, Rejection, decode_message
from simpletrack.wire.codec import encode as encode_message
from simpletrack.wire.header import peek_header
from simpletrack.wire.keys import VEHICLE_STREAM
from simpletrack.wire.models import (
    FusedSensorStatus,
    SensorSnapshot,
    SensorStatus,
    VehicleStatus,
)
from simpletrack.wire.reasons import SCHEMA_VERSION, SensorCondition

F64 = npt.NDArray[np.float64]
STATE_FORMAT = 1
_SNAP_LIMITS = DecodeLimits(max_bytes=1 << 30, max_boxes=1 << 30)


def fusion_digest(tracker_digest: str, fusion: FusionConfig) -> str:
    """What a vehicle's snapshot must match to be restored: the tracker's configuration
    and the vehicle's fusion settings."""
    return hashlib.sha256(f"{tracker_digest}|{fusion.model_dump_json()}".encode()).hexdigest()


@dataclass(frozen=True, slots=True)
class Waiting:
    """A decoded frame in the reorder buffer."""

    item: Inbound
    sensor: str
    decoded: DecodedDetections
    arrival: Arrival
    transform: F64 | None
    replayed: bool  # tracked again at a takeover: its receipt time says nothing of its clock


@dataclass
class VehicleState:
    vehicle: str
    tracker: VehicleTracker
    buffer: ReorderBuffer[Waiting]
    digest: str
    sensor: str = VEHICLE_STREAM
    id_base: int = 0  # ids are the tracker's own: it never restarts them
    arrivals: dict[str, Arrival] = field(default_factory=dict)  # each sensor's last frame
    # Each sensor's last frame the tracker took (a snapshot's: the frames still waiting in
    # the reorder buffer are not in the state, so a takeover replays them).
    taken: dict[str, Arrival] = field(default_factory=dict)
    last: Arrival | None = None  # the last frame applied (the vehicle's gap rule)
    frame: str | None = None  # "world" (poses) or "vehicle" (extrinsics): the first frame's
    per_sensor: dict[str, SensorState] = field(default_factory=dict)
    frames: int = 0  # frames applied
    active_tracks: int = 0
    last_seen: float = field(default_factory=time.monotonic)
    dirty: bool = True
    checkpoint_mark: CheckpointMark | None = None
    resets: int = 0
    implausible: int = 0
    tracked_at: deque[float] = field(default_factory=lambda: deque(maxlen=RATE_FRAMES))
    # After a takeover: messages up to this seq reached planners already (not sent again).
    published_seq: int | None = None
    epoch: int = 0  # custody epoch (docs/SCALE.md, "Fencing"): on every tracks message
    missed_by_sensor: dict[str, int] = field(default_factory=dict)  # the last ``holes``
    # Per sensor: when its last frame arrived (monotonic) and its recent stamp -> receipt.
    heard_at: dict[str, float] = field(default_factory=dict)
    lags: dict[str, deque[float]] = field(default_factory=dict)

    def heard(self, sensor: str, arrival: Arrival) -> None:
        self.heard_at[sensor] = time.monotonic()
        if arrival.received_ns is not None:
            lags = self.lags.setdefault(sensor, deque(maxlen=64))
            lags.append((arrival.received_ns - arrival.stamp_ns) * 1e-9)

    def standing(self, now: float) -> None:
        """Each sensor's standing from its buffer as of ``now``: silent or not, and the
        kept-out sensors the buffer does not wait for."""
        for sensor in self.tracker.sensors:
            self.tracker.set_silent(sensor, self.buffer.silent(sensor, now))
        self.buffer.ignored = frozenset(
            s for s, r in self.tracker.records.items() if r.condition.kept_out
        )

    def status(self, now: float) -> tuple[VehicleStatus, list[SensorStatus]]:
        """The vehicle's entry of the service status, and one sensor entry per fused
        sensor heard (what a publisher resuming its seq asks for)."""
        t = self.tracker
        fused, sensors = [], []
        for name in t.sensors:
            rec = t.records[name]
            heard = self.heard_at.get(name)
            idle = None if heard is None else round(now - heard, 3)
            lags = self.lags.get(name)
            fused.append(
                FusedSensorStatus(
                    sensor=name,
                    state=SensorCondition(rec.condition.value),
                    last_seq=rec.last_seq,
                    last_stamp_ns=rec.last_stamp_ns,
                    frames=rec.frames,
                    idle_s=idle,
                    latency_s=None if not lags else round(float(np.median(lags)), 4),
                    clock_offset_s=None if rec.delta_s is None else round(rec.delta_s, 4),
                    offset_m=None if rec.offset_m is None else [round(v, 2) for v in rec.offset_m],
                    flagged_frames=rec.kept_out,
                    detail=rec.detail[:256],
                )
            )
            if rec.last_seq is not None and idle is not None:
                sensors.append(
                    SensorStatus(
                        vehicle=self.vehicle,
                        sensor=name,
                        last_seq=rec.last_seq,
                        last_stamp_ns=rec.last_stamp_ns,
                        frames=rec.frames,
                        active_tracks=0,  # the vehicle's, counted once in its entry
                        idle_s=idle,
                    )
                )
        vehicle = VehicleStatus(
            vehicle=self.vehicle,
            seq=self.last_seq,
            last_stamp_ns=t.last_ns,
            active_tracks=self.active_tracks,
            frames=self.frames,
            late_frames=t.late,
            reprocessed_frames=t.reprocessed,
            sensors=fused,
        )
        return vehicle, sensors

    @property
    def id_next(self) -> int:
        return self.tracker.next_id

    @property
    def last_seq(self) -> int | None:
        """The seq of the last message."""
        return None if self.tracker.seq == 0 else self.tracker.seq - 1

    @property
    def last_stamp_ns(self) -> int | None:
        """The least of the sensors' last stamps taken: every frame of any sensor at or
        before it is in the state (a standby may drop what it keeps up to it)."""
        stamps = [r.last_stamp_ns for r in self.tracker.records.values()]
        taken = [s for s in stamps if s is not None]
        return min(taken) if len(taken) == len(stamps) and taken else None

    @property
    def stamp_origin_ns(self) -> int | None:
        return self.tracker.origin_ns

    def covers(self, item: Inbound) -> bool:
        """The frame was taken by this state already, or is not one of its sensors' (a
        replay skips it)."""
        names = item.key.split("/")
        sensor = names[-2] if len(names) >= 3 else ""
        if sensor not in self.tracker.records:
            return True
        stamp = peek_header(item.payload)[1]
        return stamp is not None and self.tracker.covers(sensor, stamp)

    def holes(self, items: Iterable[Inbound]) -> int:
        """Per sensor, seqs between its last taken and the newest of ``items`` that none of
        them has (frames neither a standby nor the vehicle kept)."""
        seen: dict[str, set[int]] = {}
        for item in items:
            names = item.key.split("/")
            seq = peek_header(item.payload)[0]
            if seq is not None and len(names) >= 3:
                seen.setdefault(names[-2], set()).add(seq)
        self.missed_by_sensor = {}
        for sensor, seqs in seen.items():
            rec = self.tracker.records.get(sensor)
            last = None if rec is None else rec.last_seq
            if last is None:
                continue
            top = max(seqs)
            if top - last <= 100_000:  # a restarted publisher's seq is not a gap
                self.missed_by_sensor[sensor] = sum(
                    1 for q in range(last + 1, top + 1) if q not in seqs
                )
        return sum(self.missed_by_sensor.values())

    def tracked(self, active_tracks: int) -> int:
        """Record an applied frame; returns the change in active tracks."""
        delta = active_tracks - self.active_tracks
        self.active_tracks = active_tracks
        self.frames += 1
        self.dirty = True
        self.tracked_at.append(time.monotonic())
        return delta

    def rate_hz(self, now: float) -> float:
        recent = [t for t in tuple(self.tracked_at) if now - t <= RATE_WINDOW_S]
        if len(recent) < 2:
            return 0.0
        return (len(recent) - 1) / max(recent[-1] - recent[0], 1e-9)

    def snapshot(
        self, _digest: str = "", with_tracker: bool = True, *, state_format: int
    ) -> SensorSnapshot:
        """The stream's state as a ``SensorSnapshot`` of sensor ``@vehicle``; the frames
        waiting in the reorder buffer are not in it (a takeover replays them)."""
        last = self.last
        blob = None
        if with_tracker:
            blob = msgpack.packb(
                {
                    "format": STATE_FORMAT,
                    "vehicle": self.tracker.to_bytes(state_format),
                    "arrivals": {s: _arrival_obj(a) for s, a in self.taken.items()},
                    "last": None if last is None else _arrival_obj(last),
                    "frame": self.frame,
                    "frames": self.frames,
                    "per_sensor": {
                        s: encode_message(st.snapshot(self.digest, state_format=state_format))
                        for s, st in self.per_sensor.items()
                    },
                },
                use_bin_type=True,
            )
        return SensorSnapshot(
            schema_version=SCHEMA_VERSION,
            vehicle=self.vehicle,
            sensor=VEHICLE_STREAM,
            last_seq=self.last_seq,
            last_stamp_ns=self.last_stamp_ns,
            stamp_origin_ns=self.stamp_origin_ns,
            id_base=0,
            id_next=self.id_next,
            frames=self.frames,
            last_received_ns=None if last is None else last.received_ns,
            last_session_id=None,
            config_digest=self.digest,
            tracker=blob,
            written_ns=time.time_ns(),
            epoch=self.epoch,
        )


def new_vehicle(
    vehicle: str,
    config: TrackerConfig,
    fusion: FusionConfig,
    digest: str,
    window_s: float,
    silent_after_s: float,
    id_floor: int = 0,
) -> VehicleState:
    tracker = VehicleTracker(config, fusion)
    tracker.tracker.next_id = id_floor
    buffer: ReorderBuffer[Waiting] = ReorderBuffer(fusion.names, window_s, silent_after_s)
    return VehicleState(vehicle, tracker, buffer, digest)


def vehicle_from_snapshot(
    snap: SensorSnapshot,
    config: TrackerConfig,
    fusion: FusionConfig,
    digest: str,
    new_tracker: Any,
) -> VehicleState:
    """A vehicle from its snapshot (ValueError when it cannot be read as one)."""
    if snap.tracker is None:
        raise ValueError("the snapshot holds no state")
    obj = msgpack.unpackb(snap.tracker, raw=False)
    if not isinstance(obj, dict) or obj.get("format") != STATE_FORMAT:
        raise ValueError("not a vehicle state of this format")
    state = new_vehicle(
        snap.vehicle, config, fusion, digest, fusion.window_s, fusion.silent_after_s
    )
    state.tracker = VehicleTracker.from_bytes(obj["vehicle"], config, fusion)
    state.arrivals = {s: _arrival_of(a) for s, a in obj["arrivals"].items()}
    state.taken = dict(state.arrivals)
    state.last = None if obj["last"] is None else _arrival_of(obj["last"])
    state.frame = obj["frame"]
    state.frames = int(obj["frames"])
    # Its buffer is new: the sensors live in the state are waited for as they were, not
    # found silent (a camera frame let go ahead of the lidar's stamped before it would be
    # judged against stale tracks: flagged for its clock, once after a failover in CI).
    now = time.monotonic()
    for sensor, arrival in state.taken.items():
        rec = state.tracker.records.get(sensor)
        if rec is not None and rec.condition is Condition.OK:
            state.buffer.assume_heard(sensor, arrival.stamp_ns, now)
    state.standing(now)
    for sensor, data in obj["per_sensor"].items():
        sub = decode_message(data, SensorSnapshot, _SNAP_LIMITS)
        if isinstance(sub, Rejection) or sub.tracker is None:
            raise ValueError(f"the per-sensor state of {sensor} is unreadable")
        state.per_sensor[sensor] = sensor_from_snapshot(sub, new_tracker)
    state.dirty = False
    return state


def sensor_from_snapshot(snap: SensorSnapshot, new_tracker: Any) -> SensorState:
    from simpletrack.core.tracker import Tracker

    assert snap.tracker is not None
    tracker: Tracker = Tracker.from_bytes(snap.tracker)
    last = None
    if snap.last_seq is not None and snap.last_stamp_ns is not None:
        received = snap.last_received_ns if snap.last_received_ns is not None else snap.written_ns
        last = Arrival(snap.last_seq, snap.last_stamp_ns, received, snap.last_session_id)
    return SensorState(
        vehicle=snap.vehicle,
        sensor=snap.sensor,
        tracker=tracker,
        id_base=snap.id_base,
        last=last,
        stamp_origin_ns=snap.stamp_origin_ns,
        frames=snap.frames,
        dirty=False,
    )


def _arrival_obj(a: Arrival) -> list[int | None]:
    return [a.seq, a.stamp_ns, a.received_ns, a.session_id]


def _arrival_of(o: list[int | None]) -> Arrival:
    seq, stamp = o[0], o[1]
    assert seq is not None and stamp is not None
    return Arrival(int(seq), int(stamp), o[2], o[3])


__all__ = [
    "VehicleState",
    "Waiting",
    "fusion_digest",
    "new_vehicle",
    "sensor_from_snapshot",
    "vehicle_from_snapshot",
]
