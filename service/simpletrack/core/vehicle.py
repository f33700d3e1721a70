"""One tracker for every sensor of a vehicle: the fused track list (docs/SERVICE.md,
"Vehicle fusion").

Each sensor frame is one step of the vehicle's SimpleTrack tracker, in stamp order, in the
tracking frame (world when the frames carry poses, else the vehicle's through the
extrinsic). What a frame of sensor ``s`` may do is what ``s`` can know:

- **View.** Only tracks predicted inside ``s``'s field of view (plus ``fov_margin_m``) take
  part: they may be matched by its detections, and only their life-cycle counters move.
  A track out of view is left exactly as it is.
- **Life.** A track dies when every sensor that has had it in view since its last update
  has missed it ``max_age`` times in a row (the class's max_age): a camera that misses a
  pedestrian the lidar keeps seeing kills nothing. Per track and sensor the consecutive
  misses are kept (``misses``); the track's ``time_since_update`` is their minimum.
- **Trust.** Per sensor: whether it starts tracks (and of which classes), the minimum
  score, the measurement noise of its updates, whether its scores count toward existence.
- **Existence.** A binary Bayes filter per track: a detection adds logit(score) (or
  logit(hit_probability) for a sensor whose scores are not trusted), a miss in view adds
  log(1 - detection_probability); clamped so that one observation can always move it.
- **Verification.** A sensor under verification (every one but the vehicle's reference,
  unless configured otherwise) is only watched (core/calibration.py) until its detections
  agree with the tracks the trusted sensors keep; a sensor whose clock or extrinsic is off
  is flagged and kept out the same way, so that it cannot corrupt the vehicle's tracks.
- **Late frames.** A frame stamped before the last one applied (late past the reorder
  window) is re-processed: the stored states go back to before its stamp, it is applied,
  and the frames after it again; a track born again from the same detection keeps its id,
  every other birth takes a new one (an id never names two objects). Older than
  ``history_s``: refused as late.

With one sensor, no field of view and default trust, every step is exactly the per-sensor
tracker's: same ids, boxes, scores and states (tests/core/test_vehicle.py).

Pure: arrays in, arrays out; no clocks (stamps and receipt leads come with the frames).
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass, field, replace
from enum import StrEnum
from typing import Any

import numpy as np
import numpy.typing as npt

from simpletrack.core import calibration
from simpletrack.core.boxes import Boxes, transform_boxes
from simpletrack.core.config import ClassConfig, MotionModel, OutputPolicy, TrackerConfig
from simpletrack.core.frames import Frame, Tracks
from simpletrack.core.fused_kernels import counter_in, fused_columns, report_gather, report_rows
from simpletrack.core.fusion_config import EXISTENCE_FLOOR, FusionConfig, SensorTrust
from simpletrack.core.kalman_kernels import predict_all
from simpletrack.core.lifecycle import TrackState, UpdateKind
from simpletrack.core.motion import KalmanFilter
from simpletrack.core.occlusion import occlusion
from simpletrack.core.state import TrackTable, pack, pack_array, unpack, unpack_array
from simpletrack.core.tracker import POLICY_CODES, Tracker
from simpletrack.core.tracker import STATE_FORMAT as TRACKER_STATE_FORMAT

F64 = npt.NDArray[np.float64]
I64 = npt.NDArray[np.int64]
I32 = npt.NDArray[np.int32]
I8 = npt.NDArray[np.int8]
Bool = npt.NDArray[np.bool_]

STATE_FORMAT = 1
_LOGIT_MAX = math.log((1 - EXISTENCE_FLOOR) / EXISTENCE_FLOOR)
_NO_STATES, _NO_COVARIANCES = np.zeros((0, 10)), np.zeros((0, 6, 6))  # report_gather's unused
# Tracks updated by a trusted sensor this recently are what a sensor is checked against.
REFERENCE_AGE_NS = 300_000_000
LATE_FLAG_AFTER = 3  # consecutive frames too old for the history: the sensor's clock is behind


class Condition(StrEnum):
    """A sensor's standing with its vehicle (the wire's ``sensor_state`` values)."""

    OK = "ok"
    PROBATION = "probation"  # watched, not applied, until it agrees with the trusted sensors
    SILENT = "silent"  # set by the service: no frame for silent_after_s
    CLOCK = "clock"  # stamps off: kept out
    EXTRINSIC = "extrinsic"  # detections offset from the vehicle's tracks: kept out
    UNSEEN = "unseen"  # configured, never heard

    @property
    def kept_out(self) -> bool:
        return self in (Condition.PROBATION, Condition.CLOCK, Condition.EXTRINSIC)


class Outcome(StrEnum):
    APPLIED = "applied"  # tracked: a message follows
    REPROCESSED = "reprocessed"  # late, applied in its place by re-processing: no message
    LATE = "late"  # older than the history: refused
    FLAGGED = "flagged"  # its sensor is flagged: refused
    VERIFYING = "verifying"  # its sensor is under verification: watched only


@dataclass(frozen=True, slots=True)
class SensorInput:
    """One sensor frame for its vehicle. ``boxes`` in the sensor frame; ``transform`` the
    sensor -> tracking frame 4x4 (the pose, or the extrinsic; None: the boxes are in the
    tracking frame already); ``lead_s`` the stamp minus the service's receipt time (None:
    unknown, e.g. a replayed frame)."""

    sensor: str
    seq: int
    stamp_ns: int
    boxes: Boxes
    transform: F64 | None = None
    key_frame: bool = True
    lead_s: float | None = None
    after_gap: bool = False


@dataclass(frozen=True, slots=True)
class VehicleTracks:
    """The vehicle's tracks at ``stamp_ns``, after a frame of ``sensor``: every box at that
    stamp (updated, else predicted). ``existence`` per track; ``sensor_stamp_ns`` (N, S) the
    stamp of each configured sensor's last update of each track, -1 for never."""

    seq: int
    sensor: str
    stamp_ns: int
    tracks: Tracks
    existence: F64
    sensor_stamp_ns: I64


@dataclass(frozen=True, slots=True)
class StepResult:
    outcome: Outcome
    tracks: VehicleTracks | None = None
    detail: str = ""


@dataclass(frozen=True, slots=True)
class FusedColumns:
    """Per track, aligned with the tracker's table (rows sorted by id)."""

    misses: I32  # (n, S) consecutive misses in view since the last update; -1: not in view since
    stamp_ns: I64  # (n, S) each sensor's last update of the track; -1: never
    last_kind: I8  # UpdateKind of the latest update by any sensor
    log_odds: F64  # existence, as log odds
    occluded: I32  # consecutive frames not missed for being hidden

    @classmethod
    def empty(cls, sensors: int) -> FusedColumns:
        return cls(
            np.zeros((0, sensors), dtype=np.int32),
            np.zeros((0, sensors), dtype=np.int64),
            np.zeros(0, dtype=np.int8),
            np.zeros(0),
            np.zeros(0, dtype=np.int32),
        )

    def take(self, rows: npt.ArrayLike) -> FusedColumns:
        r = np.asarray(rows)
        return FusedColumns(
            self.misses[r], self.stamp_ns[r], self.last_kind[r], self.log_odds[r],
            self.occluded[r],
        )  # fmt: skip


@dataclass
class SensorRecord:
    """What the vehicle knows of one of its sensors."""

    condition: Condition = Condition.UNSEEN
    detail: str = ""
    last_seq: int | None = None
    last_stamp_ns: int | None = None  # the last frame taken (applied, watched or refused)
    frames: int = 0  # frames applied
    kept_out: int = 0  # frames watched or refused for its condition
    agreed: int = 0  # frames of agreement while under verification
    too_old: int = 0  # consecutive frames older than the history
    monitor: calibration.MonitorState = field(default_factory=calibration.MonitorState.empty)
    offset_m: tuple[float, float] | None = None
    delta_s: float | None = None
    source: str = ""  # what set a CLOCK or EXTRINSIC condition: lead, late or monitor
    transform: F64 | None = None  # its last frame's sensor -> tracking transform (its view)

    def copy(self) -> SensorRecord:
        """A shallow copy, what ``replace(self)`` made, without its look at every field (~10
        µs a record; each frame's undo record copies every sensor's)."""
        twin = object.__new__(SensorRecord)
        twin.__dict__.update(self.__dict__)
        return twin


@dataclass(frozen=True, slots=True)
class _Births:
    """The tracks a frame started: their ids, classes and boxes (re-processing keeps these
    ids for tracks born again from the same detections)."""

    ids: I64
    cls: I32
    params: F64


@dataclass(frozen=True, slots=True)
class _Saved:
    table: TrackTable
    frame_count: int
    last_stamp: float | None
    cols: FusedColumns
    last_ns: int | None
    last_key: tuple[int, int, int] | None
    records: dict[str, SensorRecord]


@dataclass(frozen=True, slots=True)
class _Entry:
    inp: SensorInput
    key: tuple[int, int, int]
    before: _Saved
    births: _Births


class VehicleTracker:
    """The tracks of one vehicle, from the frames of its configured sensors."""

    def __init__(self, config: TrackerConfig, fusion: FusionConfig) -> None:
        self.config, self.fusion = config, fusion
        check_fusable(config, fusion)
        self.sensors = fusion.names
        self._index = {name: i for i, name in enumerate(self.sensors)}
        # The inner tracker reports every live track; the output policy is applied here,
        # where a track's freshness counts every sensor (docs/SERVICE.md).
        inner = config.with_overrides(output=OutputPolicy.NUSCENES)
        self.tracker = Tracker(inner)
        # A sensor with class overrides steps through a tracker of its own configuration;
        # the state (tracks, counters, ids) is the vehicle's one tracker's, lent for the step.
        self._steppers = {
            s: _with_classes(inner, t.classes) for s, t in fusion.sensors.items() if t.classes
        }
        self._kf = KalmanFilter(config.kalman)
        classes = config.class_names
        self._coast = np.array(
            [config.for_code(c).coast_output for c in range(len(classes))], dtype=np.int64
        )
        self._policy = POLICY_CODES[config.output]
        self._min_score = {s: np.array(t.min_score_of(classes)) for s, t in fusion.sensors.items()}
        self._r = {s: None if t.r is None else np.eye(7) * t.r for s, t in fusion.sensors.items()}
        self._spawn = {
            s: np.array([t.spawn and (t.spawn_classes is None or c in t.spawn_classes)
                         for c in classes])
            for s, t in fusion.sensors.items()
        }  # fmt: skip
        self._clearance = {s: t.spawn_clearance_m for s, t in fusion.sensors.items()}
        self.cols = FusedColumns.empty(len(self.sensors))
        self.origin_ns: int | None = None
        self.last_ns: int | None = None
        self.last_key: tuple[int, int, int] | None = None
        self.seq = 0  # the next message's
        self.records = {s: SensorRecord() for s in self.sensors}
        self.late = 0
        self.reprocessed = 0
        self._history: deque[_Entry] = deque()

    # ------------------------------------------------------------------ the frame
    def apply(self, inp: SensorInput) -> StepResult:
        """Take one frame of a configured sensor (frames of one sensor in stamp order)."""
        if inp.sensor not in self._index:
            raise ValueError(f"sensor {inp.sensor!r} is not one of {', '.join(self.sensors)}")
        key = self._key(inp)
        if self.last_key is not None and key < self.last_key:
            return self._late(inp, key)
        result, _ = self._take(inp, key, record=True, reuse=None)
        return result

    def _key(self, inp: SensorInput) -> tuple[int, int, int]:
        """The order frames are applied in: stamp, then the configured sensor order."""
        return (inp.stamp_ns, self._index[inp.sensor], inp.seq)

    def covers(self, sensor: str, stamp_ns: int) -> bool:
        """Whether a frame of ``sensor`` at ``stamp_ns`` was taken already."""
        rec = self.records.get(sensor)
        return rec is not None and rec.last_stamp_ns is not None and stamp_ns <= rec.last_stamp_ns

    def reset(self) -> None:
        """Forget every track (a new stream after a long gap); ids continue above."""
        next_id = self.tracker.next_id
        self.tracker.reset()
        self.tracker.next_id = next_id
        self.cols = FusedColumns.empty(len(self.sensors))
        self.origin_ns = None
        self._history.clear()

    def set_silent(self, sensor: str, silent: bool) -> None:
        """The service's view of the sensor's liveness (it holds the clock)."""
        rec = self.records[sensor]
        if silent and rec.condition is Condition.OK:
            rec.condition, rec.detail = Condition.SILENT, "no frame for silent_after_s"
        elif not silent and rec.condition is Condition.SILENT:
            rec.condition, rec.detail = Condition.OK, ""

    # ------------------------------------------------------------------ judging a frame
    def _judge(self, inp: SensorInput, boxes: Boxes, t: float) -> tuple[Condition, str]:
        """The sensor's condition after looking at this frame (before applying it). A flag
        of the monitor stays until the monitor's evidence clears it; a sensor under
        verification that was flagged must then agree again."""
        rec = self.records[inp.sensor]
        tol = self.fusion.clock_tolerance_s
        if inp.lead_s is not None and inp.lead_s > tol:
            rec.source = "lead"
            return Condition.CLOCK, f"stamps {inp.lead_s:.3f} s ahead of the service's clock"
        reference = self.records[self.sensors[0]]
        ahead = (inp.stamp_ns - (reference.last_stamp_ns or inp.stamp_ns)) * 1e-9
        if (
            inp.sensor != self.sensors[0]
            and reference.condition is Condition.OK
            and ahead > self.fusion.window_s + tol
        ):
            # The reference's frames before it would have come first: its clock runs ahead.
            rec.source = "lead"
            return Condition.CLOCK, f"stamps {ahead:.3f} s ahead of the reference sensor's"
        verifies = self.fusion.verifies(inp.sensor)
        trusted = not verifies or rec.condition in (Condition.OK, Condition.SILENT)
        cond = Condition.OK if trusted else Condition.PROBATION
        if not verifies and inp.sensor == self.sensors[0]:
            return Condition.OK, ""  # the reference: what the others are checked against
        kept: tuple[Condition, str] | None = None
        if rec.condition in (Condition.CLOCK, Condition.EXTRINSIC) and rec.source == "monitor":
            kept = (rec.condition, rec.detail)
        est = self._watch(inp, boxes, t)
        if est is not None:
            off = est.offset_m
            if (
                off is not None
                and math.hypot(*off) > self.fusion.extrinsic_tolerance_m
                and est.peak_votes > 2 * est.zero_votes
            ):
                rec.source = "monitor"
                return Condition.EXTRINSIC, (
                    f"detections sit ({off[0]:.1f}, {off[1]:.1f}) m from the vehicle's tracks"
                )
            if est.delta_s is not None and abs(est.delta_s) - 3 * est.delta_se > tol:
                rec.source = "monitor"
                side = "behind" if est.delta_s > 0 else "ahead of"
                return Condition.CLOCK, (
                    f"stamps {abs(est.delta_s):.3f} s {side} the captures its detections show"
                )
            kept = None
            if cond is Condition.PROBATION and est.agree:
                rec.agreed += 1
                if rec.agreed >= self.fusion.verify_frames:
                    cond = Condition.OK
        if kept is not None:
            return kept
        rec.source = ""
        return cond, ""

    def _watch(self, inp: SensorInput, boxes: Boxes, t: float) -> calibration.Estimate | None:
        """The frame against the tracks the vehicle's other trusted sensors keep."""
        s = self._index[inp.sensor]
        tr = self.tracker.tracks
        if len(tr) == 0 or len(boxes) == 0:
            return None
        others = np.array(
            [i != s and self.records[n].condition is Condition.OK
             for i, n in enumerate(self.sensors)]
        )  # fmt: skip
        if not others.any():
            return None
        recent = self.cols.stamp_ns[:, others].max(axis=1) >= inp.stamp_ns - REFERENCE_AGE_NS
        ref = recent & (tr.state == TrackState.CONFIRMED)
        if not ref.any():
            return None
        world = boxes if inp.transform is None else transform_boxes(boxes, inp.transform)
        dt = t - tr.t_update[ref]
        xy = tr.x[ref, :2] + tr.x[ref, 7:9] * dt[:, None]
        rec = self.records[inp.sensor]
        rec.monitor, est = calibration.observe(
            rec.monitor, world.params[:, :2], world.cls, xy, tr.x[ref, 7:9], tr.cls[ref]
        )
        rec.offset_m, rec.delta_s = est.offset_m, est.delta_s
        return est

    # ------------------------------------------------------------------ applying
    def _take(
        self,
        inp: SensorInput,
        key: tuple[int, int, int],
        record: bool,
        reuse: _Births | None,
    ) -> tuple[StepResult, _Births]:
        rec = self.records[inp.sensor]
        saved = self._save() if record else None
        if self.origin_ns is None:
            self.origin_ns = inp.stamp_ns
        t = (inp.stamp_ns - self.origin_ns) * 1e-9
        boxes = self._scored(inp)
        cond, detail = self._judge(inp, boxes, t)
        rec.condition, rec.detail = cond, detail
        rec.last_seq, rec.last_stamp_ns = inp.seq, max(rec.last_stamp_ns or 0, inp.stamp_ns)
        rec.too_old = 0
        rec.transform = inp.transform
        no_births = _Births(np.zeros(0, np.int64), np.zeros(0, np.int32), np.zeros((0, 7)))
        if cond.kept_out:  # changes no track, nor the vehicle's time
            rec.kept_out += 1
            outcome = Outcome.VERIFYING if cond is Condition.PROBATION else Outcome.FLAGGED
            return StepResult(outcome, detail=detail), no_births
        rec.frames += 1
        out, births = self._step(inp, boxes, t, reuse)
        self._advance_key(key)
        if record and saved is not None:
            self._remember(inp, key, saved, births)
        report = VehicleTracks(
            self.seq, inp.sensor, inp.stamp_ns, *self._report(out, t, self._index[inp.sensor])
        )
        self.seq += 1
        return StepResult(Outcome.APPLIED, report), births

    def _advance_key(self, key: tuple[int, int, int]) -> None:
        if self.last_key is None or key > self.last_key:
            self.last_key = key
            self.last_ns = key[0]

    def _scored(self, inp: SensorInput) -> Boxes:
        """The frame's boxes without those under the sensor's minimum score."""
        b = inp.boxes
        floor = self._min_score[inp.sensor]
        if not floor.any() or len(b) == 0:
            return b
        keep = b.score >= floor[np.clip(b.cls, 0, floor.size - 1)]
        return b if keep.all() else b.take(np.flatnonzero(keep))

    def _in_view(self, inp: SensorInput, t: float) -> Bool:
        """The tracks this frame takes part for: those predicted inside the sensor's field
        of view (plus the margin), and those no other sensor that can help sees (a track
        that left every view ages on every frame, as it would with one sensor)."""
        tr = self.tracker.tracks
        if len(tr) == 0:
            return np.ones(0, dtype=bool)
        if all(_full(t) for t in self.fusion.sensors.values()):
            return np.ones(len(tr), dtype=bool)
        xyz = tr.x[:, :3].copy()
        xyz[:, :2] += tr.x[:, 7:9] * (t - tr.t_update)[:, None]
        view = self._view(inp.sensor, inp.transform, xyz)
        seen_by_other = np.zeros(len(tr), dtype=bool)
        for name, rec in self.records.items():
            if name != inp.sensor and rec.condition is Condition.OK:
                seen_by_other |= self._view(name, rec.transform, xyz)
        return np.asarray(view | ~seen_by_other, dtype=bool)

    def _hidden(self, sub: TrackTable, cols: FusedColumns, inp: SensorInput, t: float) -> Bool:
        """Tracks in view that nearer ones hide from the sensor (``occlusion``), for at most
        ``occluded_max_frames`` frames in a row."""
        limit = self.fusion.occlusion
        n = len(sub)
        if limit <= 0 or n < 2:
            return np.zeros(n, dtype=bool)
        xyz = sub.x[:, :3].copy()
        xyz[:, :2] += sub.x[:, 7:9] * (t - sub.t_update)[:, None]
        yaw = sub.x[:, 3].copy()
        if inp.transform is not None:
            inv = np.linalg.inv(inp.transform)
            xyz = xyz @ inv[:3, :3].T + inv[:3, 3]
            yaw = yaw + math.atan2(inv[1, 0], inv[0, 0])
        hidden = occlusion(xyz[:, :2], yaw, sub.x[:, 4], sub.x[:, 5]) > limit
        return np.asarray(hidden & (cols.occluded < self.fusion.occluded_max_frames), dtype=bool)

    def _view(self, sensor: str, transform: F64 | None, xyz: F64) -> Bool:
        """Points (tracking frame) inside ``sensor``'s view plus the margin, placed by its
        sensor -> tracking transform (None: the sensor frame is the tracking frame)."""
        trust = self.fusion.sensors[sensor]
        if _full(trust):
            return np.ones(xyz.shape[0], dtype=bool)
        if transform is not None:
            inv = np.linalg.inv(transform)
            xyz = xyz @ inv[:3, :3].T + inv[:3, 3]
        r = np.hypot(xyz[:, 0], xyz[:, 1])
        margin = self.fusion.fov_margin_m
        ok = (r >= trust.min_range_m - margin) & (r <= trust.max_range_m + margin)
        if trust.fov_deg < 360.0:
            bearing = np.abs(np.arctan2(xyz[:, 1], xyz[:, 0]))
            half = math.radians(trust.fov_deg) / 2 + np.arctan2(margin, np.maximum(r, 1e-6))
            ok &= bearing <= half
        return np.asarray(ok, dtype=bool)

    def _step(
        self, inp: SensorInput, boxes: Boxes, t: float, reuse: _Births | None
    ) -> tuple[Tracks, _Births]:
        """One step of the inner tracker over the tracks in view; the others are kept."""
        s = self._index[inp.sensor]
        tracker = self.tracker
        table, cols = tracker.tracks, self.cols
        view = self._in_view(inp, t)
        iv, ov = np.flatnonzero(view), np.flatnonzero(~view)
        sub, sub_cols = (table, cols) if ov.size == 0 else (table.take(iv), cols.take(iv))
        counter = counter_in(sub_cols.misses, s)
        hidden = self._hidden(sub, sub_cols, inp, t)
        if hidden.any():  # its own "+ 1" leaves a hidden track's counter where it was
            counter = np.where(hidden, sub.time_since_update - 1, counter).astype(np.int32)
        tracker.tracks = replace(sub, time_since_update=counter)
        first_new = tracker.next_id
        frame = Frame(
            boxes, t, pose=inp.transform, key_frame=inp.key_frame, after_gap=inp.after_gap
        )
        stepper = self._steppers.get(inp.sensor)
        if stepper is None:
            out = tracker.step(frame, r=self._r[inp.sensor])
        else:
            _lend(tracker, stepper)
            out = stepper.step(frame, r=self._r[inp.sensor])
            _lend(stepper, tracker)
        new = tracker.tracks
        born = new.ids >= first_new
        keep_born = self._spawn[inp.sensor][new.cls] | ~born
        clearance = self._clearance[inp.sensor]
        if clearance > 0 and born.any():
            keep_born &= ~born | ~_crowded(new, born, out, table, clearance)
        if not keep_born.all():
            new, out = _without(new, out, keep_born)
            born = new.ids >= first_new
        new_ids, births = _birth_ids(new.ids, born, new.cls, new.x[:, :7], first_new, reuse)
        if reuse is not None or not np.array_equal(new_ids, new.ids):
            out = replace(out, ids=_map_ids(out.ids, new.ids, new_ids))
            new = replace(new, ids=new_ids)
        tracker.next_id = max(first_new, int(births.ids.max(initial=first_new - 1)) + 1)
        new_cols = self._columns(sub_cols, sub.ids, new, born, out, s, inp, hidden)
        if ov.size:
            new = new.concat(table.take(ov))
            new_cols = _concat(new_cols, cols.take(ov))
        order = np.argsort(new.ids, kind="stable")
        if not np.array_equal(order, np.arange(order.size)):
            new, new_cols = new.take(order), new_cols.take(order)
        tracker.tracks, self.cols = new, new_cols
        return out, births

    def _columns(
        self,
        before: FusedColumns,
        before_ids: I64,
        new: TrackTable,
        born: Bool,
        out: Tracks,
        s: int,
        inp: SensorInput,
        hidden_before: Bool,
    ) -> FusedColumns:
        """The fused columns of the tracks in view after this frame (``new``'s rows);
        ``hidden_before``: the tracks before it (``before_ids``) hidden from the sensor."""
        trust = self.fusion.sensors[inp.sensor]
        misses, stamps, kind, odds, occluded = fused_columns(
            before.misses, before.stamp_ns, before.last_kind, before.log_odds, before.occluded,
            hidden_before, before_ids, new.ids, born, new.update,
            self._evidence(new.match_score, trust.existence, trust), s, bool(inp.key_frame),
            inp.stamp_ns, math.log1p(-trust.detection_probability), _LOGIT_MAX,
        )  # fmt: skip
        return FusedColumns(misses, stamps, kind, odds, occluded)

    @staticmethod
    def _evidence(score: F64, trusted: bool, trust: Any) -> F64:
        if trusted:
            p = np.clip(score, EXISTENCE_FLOOR, 1 - EXISTENCE_FLOOR)
        else:
            p = np.full(
                score.shape, min(max(trust.hit_probability, EXISTENCE_FLOOR), 1 - EXISTENCE_FLOOR)
            )
        return np.asarray(np.log(p / (1 - p)), dtype=np.float64)

    # ------------------------------------------------------------------ the report
    def _report(self, out: Tracks, t: float, s: int) -> tuple[Tracks, F64, I64]:
        """Every track the output policy reports, at ``t``: those in the step from its
        report (``out``: every live track in view), the others predicted here.

        A track is *fresh* (what the policies call matched) when the latest update by any
        sensor was a stage-1 match and no sensor that has had it in view since has missed
        it: matched by this frame, or updated by another sensor since this one last
        updated it and missed by none. With one sensor: matched on this frame."""
        table, cols = self.tracker.tracks, self.cols
        tsu = table.time_since_update
        min_e = self.fusion.min_existence
        kind, fresh, coast, keep, where, in_step = report_rows(
            out.ids, out.update, table.ids, tsu, cols.stamp_ns, cols.last_kind, s, table.state,
            table.cls, self._coast, cols.occluded, cols.log_odds, self._policy, min_e > 0,
            _logit(min_e) if min_e > 0 else 0.0,
        )  # fmt: skip
        rows = np.flatnonzero(keep)
        kalman = self.config.motion is MotionModel.KALMAN
        away = np.flatnonzero(~in_step & keep)
        x_away, p_away = _NO_STATES, _NO_COVARIANCES
        if away.size:
            dt = t - table.t_update[away]
            if kalman:
                x_away, p_away = predict_all(table.x[away], table.p[away], dt, self._kf.q)
            else:
                x_away = table.x[away].copy()
                x_away[:, :3] += table.x[away, 7:10] * dt[:, None]
        out_cov = _NO_COVARIANCES if out.covariance is None else out.covariance
        box, cov, score, velocity, age_s, tsu_s = report_gather(
            rows, in_step, where, out.boxes.params, out_cov, x_away, p_away, kalman, fresh,
            coast, table.match_score, table.score, table.x, t, table.t_birth, table.t_update,
        )  # fmt: skip
        tracks = Tracks(
            ids=table.ids[rows],
            boxes=Boxes(params=box, score=score, cls=table.cls[rows]),
            velocity=velocity,
            state=table.state[rows],
            update=kind[rows],
            hits=table.hits[rows],
            age=table.age[rows],
            time_since_update=tsu[rows],
            covariance=cov if kalman else None,
            age_s=age_s,
            time_since_update_s=tsu_s,
        )
        existence = 1.0 / (1.0 + np.exp(-cols.log_odds[rows]))
        return tracks, existence, cols.stamp_ns[rows]

    # ------------------------------------------------------------------ late frames
    def _save(self) -> _Saved:
        tr = self.tracker
        return _Saved(
            tr.tracks, tr.frame_count, tr.last_stamp, self.cols, self.last_ns, self.last_key,
            {s: r.copy() for s, r in self.records.items()},
        )  # fmt: skip

    def _restore(self, saved: _Saved) -> None:
        tr = self.tracker
        tr.tracks, tr.frame_count, tr.last_stamp = saved.table, saved.frame_count, saved.last_stamp
        self.cols, self.last_ns, self.last_key = saved.cols, saved.last_ns, saved.last_key
        self.records = {s: r.copy() for s, r in saved.records.items()}

    def _remember(
        self, inp: SensorInput, key: tuple[int, int, int], saved: _Saved, births: _Births
    ) -> None:
        self._history.append(_Entry(inp, key, saved, births))
        horizon = key[0] - round(self.fusion.history_s * 1e9)
        while self._history and self._history[0].key[0] < horizon:
            self._history.popleft()

    def _late(self, inp: SensorInput, key: tuple[int, int, int]) -> StepResult:
        """A frame stamped before the last one applied: re-processed within the history,
        refused beyond it."""
        rec = self.records[inp.sensor]
        hist = self._history
        if not hist or key < hist[0].key:
            self.late += 1
            rec.too_old += 1
            behind = ((self.last_ns or inp.stamp_ns) - inp.stamp_ns) * 1e-9
            rec.last_seq = inp.seq
            rec.last_stamp_ns = max(rec.last_stamp_ns or 0, inp.stamp_ns)
            if rec.too_old >= LATE_FLAG_AFTER:
                rec.condition, rec.source = Condition.CLOCK, "late"
                rec.detail = (
                    f"frames {behind:.3f} s behind the vehicle's other sensors, older than "
                    f"history_s"
                )
            return StepResult(
                Outcome.LATE,
                detail=f"stamp {behind:.3f} s before the vehicle's last applied frame, "
                f"beyond history_s={self.fusion.history_s}",
            )
        k = next(i for i, e in enumerate(hist) if e.key > key)
        redo = list(hist)[k:]
        self._restore(redo[0].before)
        for _ in range(len(hist) - k):
            hist.pop()
        seq = self.seq
        first, _ = self._take(inp, key, record=True, reuse=None)
        for e in redo:
            self._take(e.inp, e.key, record=True, reuse=e.births)
        self.seq = seq  # nothing of the re-processing is published
        self.reprocessed += len(redo)
        if first.outcome is not Outcome.APPLIED:
            return first
        return StepResult(Outcome.REPROCESSED, detail=f"{len(redo)} frames re-applied after it")

    # ------------------------------------------------------------------ persistence
    def to_bytes(self, state_format: int = TRACKER_STATE_FORMAT) -> bytes:
        """Everything to continue exactly where this vehicle is, but the re-processing
        history (a frame older than a restored state is refused as late); its tracker's
        tracks in ``state_format`` (``Tracker.to_bytes``)."""
        c = self.cols
        return pack(
            {
                "format": STATE_FORMAT,
                "sensors": list(self.sensors),
                "tracker": self.tracker.to_bytes(state_format),
                "misses": pack_array(c.misses),
                "stamp_ns": pack_array(c.stamp_ns),
                "last_kind": pack_array(c.last_kind),
                "log_odds": pack_array(c.log_odds),
                "occluded": pack_array(c.occluded),
                "origin_ns": self.origin_ns,
                "last_ns": self.last_ns,
                "last_key": None if self.last_key is None else list(self.last_key),
                "seq": self.seq,
                "late": self.late,
                "reprocessed": self.reprocessed,
                "records": {s: _record_obj(r) for s, r in self.records.items()},
            }
        )

    @classmethod
    def from_bytes(cls, blob: bytes, config: TrackerConfig, fusion: FusionConfig) -> VehicleTracker:
        """A vehicle from ``to_bytes``; its tracker configuration must be ``config`` (the
        caller checks the digest) and its sensors the configured ones."""
        obj = unpack(blob)
        if obj.get("format") != STATE_FORMAT:
            raise ValueError(f"unsupported vehicle state format {obj.get('format')!r}")
        if tuple(obj["sensors"]) != fusion.names:
            raise ValueError(
                f"vehicle state of sensors {obj['sensors']}, configured {list(fusion.names)}"
            )
        v = cls(config, fusion)
        inner = Tracker.from_bytes(obj["tracker"])
        v.tracker.tracks, v.tracker.frame_count = inner.tracks, inner.frame_count
        v.tracker.next_id, v.tracker.last_stamp = inner.next_id, inner.last_stamp
        v.cols = FusedColumns(
            unpack_array(obj["misses"]).astype(np.int32),
            unpack_array(obj["stamp_ns"]).astype(np.int64),
            unpack_array(obj["last_kind"]).astype(np.int8),
            unpack_array(obj["log_odds"]).astype(np.float64),
            unpack_array(obj["occluded"]).astype(np.int32),
        )
        v.origin_ns, v.last_ns, v.seq = obj["origin_ns"], obj["last_ns"], int(obj["seq"])
        key = obj["last_key"]
        v.last_key = None if key is None else (int(key[0]), int(key[1]), int(key[2]))
        v.late, v.reprocessed = int(obj["late"]), int(obj["reprocessed"])
        v.records = {s: _record_of(o) for s, o in obj["records"].items()}
        return v

    @property
    def next_id(self) -> int:
        """The lowest id no track of this vehicle has had."""
        return self.tracker.next_id

    @next_id.setter
    def next_id(self, value: int) -> None:
        self.tracker.next_id = value

    def __len__(self) -> int:
        return len(self.tracker.tracks)


# ---------------------------------------------------------------------------- helpers
def _crowded(
    new: TrackTable, born: Bool, out: Tracks, before: TrackTable, clearance: float
) -> Bool:
    """Births (rows of ``new``) within ``clearance`` of a track of their class that this
    step left without an update, where the step put it (its report), or of one it did not
    see (out of view: where it was last put)."""
    not_updated = out.update == UpdateKind.COASTED
    xy = [out.boxes.params[not_updated, :2]]
    cls = [out.boxes.cls[not_updated]]
    away = ~np.isin(before.ids, out.ids)
    xy.append(before.out_box[away, :2])
    cls.append(before.cls[away])
    other_xy, other_cls = np.concatenate(xy), np.concatenate(cls)
    b = np.flatnonzero(born)
    d = np.hypot(*(new.x[b, None, :2] - other_xy[None, :, :2]).transpose(2, 0, 1))
    near = ((d <= clearance) & (new.cls[b, None] == other_cls[None, :])).any(axis=1)
    out_mask = np.zeros(len(new), dtype=bool)
    out_mask[b] = near
    return out_mask


def check_fusable(config: TrackerConfig, fusion: FusionConfig) -> None:
    """ValueError naming the class (and sensor) that sets a per-class motion model, process
    noise or lost tracks (docs/MOTION.md): a fused vehicle's report predicts the tracks no
    sensor saw with the tracker's constant-velocity filter, and its own life cycle decides
    what is shown; neither follows a model's states, a class's noise or a lost track yet."""
    sources: list[tuple[str, dict[str, dict[str, Any]]]] = [
        ("", {n: c.model_dump() for n, c in config.classes.items()})
    ]
    sources += [(f"fusion.sensors.{s}.classes.", t.classes) for s, t in fusion.sensors.items()]
    for where, classes in sources:
        for name, fields in classes.items():
            model = str(fields.get("motion_model", "cv"))
            revive = int(fields.get("revive_frames", 0))
            noise = fields.get("process_noise")
            if model != "cv" or revive or noise is not None:
                raise ValueError(
                    f"{where}{name}: motion_model {model}, revive_frames {revive}, "
                    f"process_noise {noise}: a fused vehicle tracks with motion_model cv, "
                    "revive_frames 0 and the tracker's kalman noise (per-sensor trackers take "
                    "all three; docs/MOTION.md)"
                )


def _with_classes(config: TrackerConfig, changes: dict[str, dict[str, Any]]) -> Tracker:
    classes = dict(config.classes)
    for name, fields in changes.items():
        if name not in classes:
            raise ValueError(f"class {name!r} is not one of {', '.join(classes)}")
        classes[name] = ClassConfig.model_validate({**classes[name].model_dump(), **fields})
    return Tracker(config.with_overrides(classes=classes))


def _lend(source: Tracker, target: Tracker) -> None:
    """Move the tracker state (tracks, frame counter, ids, last stamp) over."""
    target.tracks, target.frame_count = source.tracks, source.frame_count
    target.next_id, target.last_stamp = source.next_id, source.last_stamp


def _full(trust: SensorTrust) -> bool:
    """The sensor sees everywhere."""
    return trust.fov_deg >= 360.0 and trust.min_range_m == 0 and math.isinf(trust.max_range_m)


def _logit(p: float) -> float:
    p = min(max(p, EXISTENCE_FLOOR), 1 - EXISTENCE_FLOOR)
    return math.log(p / (1 - p))


def _without(table: TrackTable, out: Tracks, keep: Bool) -> tuple[TrackTable, Tracks]:
    """The table and report without the rows not kept (births a sensor may not make)."""
    gone = table.ids[~keep]
    table = table.take(np.flatnonzero(keep))
    k = ~np.isin(out.ids, gone)
    if k.all():
        return table, out
    return table, _take_tracks(out, np.flatnonzero(k))


def _take_tracks(out: Tracks, rows: I64) -> Tracks:
    return Tracks(
        ids=out.ids[rows],
        boxes=out.boxes.take(rows),
        velocity=out.velocity[rows],
        state=out.state[rows],
        update=out.update[rows],
        hits=out.hits[rows],
        age=out.age[rows],
        time_since_update=out.time_since_update[rows],
        covariance=None if out.covariance is None else out.covariance[rows],
        age_s=None if out.age_s is None else out.age_s[rows],
        time_since_update_s=None
        if out.time_since_update_s is None
        else out.time_since_update_s[rows],
    )


def _birth_ids(
    ids: I64, born: Bool, cls: I32, params: F64, first: int, reuse: _Births | None
) -> tuple[I64, _Births]:
    """Ids of this step's births: consecutive from ``first``; under re-processing a birth
    from the same detection as before (same class, bit-identical box) keeps its old id."""
    new = ids.copy()
    rows = np.flatnonzero(born)
    if reuse is None or reuse.ids.size == 0:  # the usual frame: consecutive, nothing to match
        new[rows] = np.arange(first, first + rows.size, dtype=np.int64)
        return new, _Births(new[rows], cls[rows].copy(), params[rows].copy())
    nxt = first
    for r in rows.tolist():
        got = None
        same = (reuse.cls == cls[r]) & (reuse.params == params[r]).all(axis=1)
        hit = np.flatnonzero(same)
        if hit.size:
            got = int(reuse.ids[hit[0]])
        if got is None:
            got = nxt
            nxt += 1
        new[r] = got
    return new, _Births(new[rows], cls[rows].copy(), params[rows].copy())


def _map_ids(values: I64, old: I64, new: I64) -> I64:
    """``values`` (each one of ``old``) renamed as ``new`` names them."""
    order = np.argsort(old, kind="stable")
    return np.asarray(new[order[np.searchsorted(old[order], values)]], dtype=np.int64)


def _concat(a: FusedColumns, b: FusedColumns) -> FusedColumns:
    return FusedColumns(
        np.concatenate([a.misses, b.misses]),
        np.concatenate([a.stamp_ns, b.stamp_ns]),
        np.concatenate([a.last_kind, b.last_kind]),
        np.concatenate([a.log_odds, b.log_odds]),
        np.concatenate([a.occluded, b.occluded]),
    )


def _record_obj(r: SensorRecord) -> dict[str, Any]:
    m = r.monitor
    return {
        "condition": r.condition.value, "detail": r.detail, "last_seq": r.last_seq,
        "last_stamp_ns": r.last_stamp_ns, "frames": r.frames, "kept_out": r.kept_out,
        "agreed": r.agreed, "too_old": r.too_old, "source": r.source,
        "votes": pack_array(m.votes), "normal": pack_array(m.normal), "rhs": pack_array(m.rhs),
        "sums": pack_array(m.sums),
        "transform": None if r.transform is None else pack_array(r.transform),
    }  # fmt: skip


def _record_of(o: dict[str, Any]) -> SensorRecord:
    return SensorRecord(
        condition=Condition(o["condition"]),
        detail=o["detail"],
        last_seq=o["last_seq"],
        last_stamp_ns=o["last_stamp_ns"],
        frames=int(o["frames"]),
        kept_out=int(o["kept_out"]),
        agreed=int(o["agreed"]),
        too_old=int(o["too_old"]),
        source=str(o["source"]),
        transform=None if o["transform"] is None else unpack_array(o["transform"]),
        monitor=calibration.MonitorState(
            unpack_array(o["votes"]), unpack_array(o["normal"]), unpack_array(o["rhs"])
        ),
    )


__all__ = [
    "Condition",
    "FusedColumns",
    "Outcome",
    "SensorInput",
    "StepResult",
    "VehicleTracker",
    "VehicleTracks",
]
