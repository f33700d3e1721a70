"""SimpleTrack: one tracker, many tracks, one ``step`` per frame.

A frame's way: drop degenerate boxes → world frame → class-aware NMS → predict every
track → stage-1 association per class → stage-2 life extension → life cycle → births →
deaths → output policy. Pure: arrays in, arrays out; the only state is ``TrackTable``.
The per-class score and life-cycle options (config.ClassConfig: track_score, delete_below,
coast_output, gate_widening, max_position_std) are all off by default.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np
import numpy.typing as npt

from simpletrack.core import gate, geometry
from simpletrack.core.advance_kernels import (
    COAST_OUTPUT,
    DELETE_BELOW,
    FUSED,
    MAX_AGE,
    MAX_POSITION_STD,
    MIN_HITS,
    N_OPTIONS,
    POLICY_NUSCENES,
    POLICY_PAPER,
    POLICY_REFERENCE,
    REVIVE,
    SCORE_DECAY,
    advance,
)
from simpletrack.core.assignment_kernels import INFEASIBLE, stage1_dense
from simpletrack.core.association import Assignment, assign, assign_pairs
from simpletrack.core.boxes import F64, YAW, Boxes, transform_boxes
from simpletrack.core.config import (
    ClassConfig,
    Matcher,
    Metric,
    MotionModel,
    OutputPolicy,
    TieOrder,
    TrackerConfig,
    TrackScore,
    VerticalOverlap,
)
from simpletrack.core.frames import Frame, Tracks
from simpletrack.core.lifecycle import UpdateKind
from simpletrack.core.motion import (
    MODEL_CODES,
    ConstantVelocity,
    KalmanFilter,
    class_noise,
    predicted_boxes,
)
from simpletrack.core.motion_kernels import predict_models
from simpletrack.core.nms import NMS_WALK_BOXES, drop_degenerate, nms, nms_order
from simpletrack.core.pair_kernels import NOT_OVERLAP, class_table, overlap_kind
from simpletrack.core.pairs import DENSE_CELLS, PairTable, far_cost
from simpletrack.core.reassociation import reassociate
from simpletrack.core.revive_kernels import gate_dense, gate_pairs, lost_tracks
from simpletrack.core.state import TrackTable, pack, unpack
from simpletrack.core.step_kernels import (
    FAR_COST,
    GATE_WIDENING,
    HUNGARIAN,
    MAX_DISTANCE,
    N_ASSOCIATION,
    REVIVE_FRAMES,
    REVIVE_GATE,
    SCORE_HIGH,
    SCORE_LOW,
    STAGE2_MAX,
    TWO_STAGE,
    WIDENED,
    InfeasibleBlock,
    step_frame,
)
from simpletrack.core.step_kernels import MAX_AGE as ASSOC_MAX_AGE

# The byte form of a tracker's state: 1 writes every cell of every column, 2 leaves out the
# cells that are zero in every track (a third of the bytes with a Kalman filter's covariance).
# Both are read; a reader from before 2 refuses a state of 2 ("unsupported ... format").
STATE_FORMAT = 2
STATE_FORMATS = (1, 2)
POLICY_CODES = {
    OutputPolicy.PAPER: POLICY_PAPER,
    OutputPolicy.REFERENCE: POLICY_REFERENCE,
    OutputPolicy.NUSCENES: POLICY_NUSCENES,
}
_NO_VELOCITY = np.zeros((0, 2))
_NO_ORDER = np.zeros(0, dtype=np.int64)  # step_frame: the STABLE order, computed there
_METRICS = tuple(Metric)
I64 = npt.NDArray[np.int64]


class Tracker:
    """The SimpleTrack tracker of one sensor stream. IDs are unique per instance, never reused."""

    def __init__(self, config: TrackerConfig) -> None:
        self.config = config
        self._kf = KalmanFilter(config.kalman)
        self._cv = ConstantVelocity()
        codes = range(len(config.classes))
        cc = [config.for_code(c) for c in codes]
        self._nms_iou = np.array([config.for_code(c).nms_iou for c in codes])
        self._score_high = np.array([config.for_code(c).score_high for c in codes])
        self._max_age = np.array([config.for_code(c).max_age for c in codes], dtype=np.int64)
        self._score_low = np.array([config.for_code(c).score_low for c in codes])
        self._two_stage = np.array([config.for_code(c).two_stage for c in codes], dtype=bool)
        self._stage2_max = np.array([config.for_code(c).stage2_max_distance for c in codes])
        self._metric_code = np.array(
            [_METRICS.index(config.for_code(c).metric) for c in codes], dtype=np.int64
        )
        self._overlap_kind = np.array([_overlap_kind(c.metric) for c in cc], dtype=np.int64)
        self._numpy_metric = self._overlap_kind == NOT_OVERLAP
        # One table serves both stages: a gated class lists what either could accept, the
        # stage-1 gate at its widest (gate_widening).
        self._gate_distance = np.array(
            [max(c.widest_max_distance, c.stage2_max_distance) for c in cc]
        )
        self._far_cost = np.array([far_cost(c) for c in cc], dtype=np.float64)
        self._hungarian = np.array([c.matcher is Matcher.HUNGARIAN for c in cc], dtype=bool)
        self._widened = np.array([c.gate_widening > 0 for c in cc], dtype=bool)
        self._max_distance = np.array([c.max_distance for c in cc])
        self._gate_widening = np.array([c.gate_widening for c in cc])
        # Off is a bound nothing crosses: -inf for a score, +inf for a deviation.
        options = np.zeros((len(cc), N_OPTIONS))
        for code, c in enumerate(cc):
            options[code, FUSED] = c.track_score is TrackScore.FUSED
            options[code, SCORE_DECAY] = c.score_decay
            options[code, MIN_HITS] = c.min_hits
            options[code, MAX_AGE] = c.max_age
            options[code, DELETE_BELOW] = _or(c.delete_below, -np.inf)
            options[code, MAX_POSITION_STD] = _or(c.max_position_std, np.inf)
            options[code, COAST_OUTPUT] = c.coast_output
            options[code, REVIVE] = c.revive_frames
        self._class_options = options
        # Motion models (core/motion_kernels.py): a 12-d state when a class has one.
        # Also for a per-class process noise alone: predict_all has one Q for every track.
        self._models = config.state_dim > 10 or any(c.process_noise is not None for c in cc)
        self._model_code = np.array([MODEL_CODES[c.motion_model] for c in cc], dtype=np.int64)
        self._p0, self._q_diag = class_noise(config)
        assoc = np.zeros((len(cc), N_ASSOCIATION))
        for code, c in enumerate(cc):
            assoc[code, SCORE_HIGH] = c.score_high
            assoc[code, SCORE_LOW] = c.score_low
            assoc[code, TWO_STAGE] = c.two_stage
            assoc[code, STAGE2_MAX] = c.stage2_max_distance
            assoc[code, MAX_DISTANCE] = c.max_distance
            assoc[code, GATE_WIDENING] = c.gate_widening
            assoc[code, ASSOC_MAX_AGE] = c.max_age
            assoc[code, FAR_COST] = self._far_cost[code]
            assoc[code, HUNGARIAN] = c.matcher is Matcher.HUNGARIAN
            assoc[code, WIDENED] = c.gate_widening > 0
            assoc[code, REVIVE_FRAMES] = c.revive_frames
            assoc[code, REVIVE_GATE] = _or(c.revive_gate, np.inf)
        self._association = assoc
        self._policy = POLICY_CODES[config.output]
        # An ordinary frame in one compiled call (core/step_kernels.py) unless a class is
        # measured in numpy; the staged path below is the same arithmetic, step by step.
        self._fused = not self._numpy_metric.any()
        self.reset()

    def reset(self) -> None:
        """Forget every track; IDs restart from 0 (a new stream)."""
        self.tracks = TrackTable.empty(self.config.state_dim)
        self.frame_count = 0
        self.next_id = 0
        self.last_stamp: float | None = None

    # ------------------------------------------------------------------ the frame
    def step(self, frame: Frame, r: npt.NDArray[np.float64] | None = None) -> Tracks:
        """Track one frame. ``r``: this frame's measurement noise (7, 7) instead of the
        configured one (a fused vehicle's noisier sensor, core/vehicle.py)."""
        if r is None:
            return self._step(frame)
        configured, self._kf.r = self._kf.r, np.asarray(r, dtype=np.float64)
        try:
            return self._step(frame)
        finally:
            self._kf.r = configured

    def _step(self, frame: Frame) -> Tracks:
        if self.last_stamp is not None and frame.stamp < self.last_stamp:
            raise ValueError(f"stamp {frame.stamp} is before the last one {self.last_stamp}")
        if len(frame.boxes) and int(frame.boxes.cls.max(initial=0)) >= len(self.config.classes):
            raise ValueError(f"class code {int(frame.boxes.cls.max())} has no config")
        self.frame_count += 1
        n = len(frame.boxes)
        # Every class block dense (core/pairs.py) and every NMS class walked whole (nms.py),
        # whatever the boxes dropped and suppressed; class codes checked by nms() there.
        if (
            self._fused
            and not frame.after_gap
            and n * len(self.tracks) <= DENSE_CELLS
            and n <= NMS_WALK_BOXES
            and (n == 0 or frame.boxes.cls.min() >= 0)
        ):
            try:
                return self._step_frame(frame)
            except InfeasibleBlock:
                pass  # the staged path raises scipy's error for the same block
        dets = self._preprocess(frame)
        key = frame.key_frame
        tr = self.tracks

        x_pred, p_pred = self._predict(tr, frame.stamp)
        pred_box = predicted_boxes(x_pred)

        # Stage 1: detections over the (per-class or non-key) high threshold.
        high = (
            self._score_high[dets.cls]
            if key
            else np.full(len(dets), self.config.non_key.score_high)
        )
        is_high = dets.score >= high
        # Stage 2: detections over the low threshold (classes with two-stage association).
        if key:
            is_low = (dets.score > self._score_low[dets.cls]) & self._two_stage[dets.cls]
        else:
            is_low = dets.score > self.config.non_key.score_low
        # One distance table for both stages: the candidates of either against every track.
        pool = np.flatnonzero(is_high | is_low)
        table = self._distance_table(dets.params[pool], dets.cls[pool], tr.cls, pred_box, p_pred)
        assoc = self._association
        lost = lost_tracks(
            tr.cls.astype(np.int64),
            tr.time_since_update,
            tr.state,
            assoc[:, REVIVE_FRAMES],
            assoc[:, ASSOC_MAX_AGE],
        )
        if lost.any():
            table = self._gate_lost(
                table, dets.params[pool], dets.cls[pool], tr.cls, pred_box, p_pred, lost
            )
        row = np.full(len(dets), -1, dtype=np.int64)
        row[pool] = np.arange(pool.size)

        cand = np.flatnonzero(is_high)
        matched_det, matched_trk, unmatched_det = self._stage1(
            dets.cls, cand, row[cand], tr.cls, self._stage1_reach(tr), table
        )
        update = np.full(len(tr), UpdateKind.COASTED, dtype=np.int8)
        update[matched_trk] = UpdateKind.MATCHED
        extended = self._stage2(row[is_low], tr.cls, table, update, key, lost)
        update[extended] = UpdateKind.EXTENDED
        if frame.after_gap:
            matched_det, matched_trk, unmatched_det = self._across_gap(
                dets, unmatched_det, matched_det, matched_trk, tr, pred_box,
                (update == UpdateKind.COASTED) & ~lost, frame.stamp,
            )  # fmt: skip
            update[matched_trk] = UpdateKind.MATCHED

        return self._advance(
            tr, x_pred, p_pred, pred_box, update, matched_det, matched_trk, extended,
            unmatched_det, dets, key, frame.stamp,
        )  # fmt: skip

    def _step_frame(self, frame: Frame) -> Tracks:
        boxes, drop, order = frame.boxes, True, _NO_ORDER
        if frame.pose is not None or self.config.tie_order is TieOrder.REFERENCE:
            boxes, drop = self._clean(frame), False
            if self.config.tie_order is TieOrder.REFERENCE and len(boxes):
                order = nms_order(boxes, TieOrder.REFERENCE)
        kalman = self.config.motion is MotionModel.KALMAN
        velocity = _NO_VELOCITY if boxes.velocity is None else _writable(boxes.velocity)
        out = step_frame(
            *self.tracks.step_columns(),
            _writable(boxes.params), _writable(boxes.score), _writable(boxes.cls), velocity,
            boxes.velocity is not None, drop, order, self._nms_iou,
            frame.key_frame, kalman, self.frame_count, self.next_id, float(frame.stamp),
            self._association, self._overlap_kind,
            self.config.vertical_overlap is VerticalOverlap.EXACT,
            self.config.non_key.score_high, self.config.non_key.score_low,
            self._kf.q, self._kf.r, self._p0, self._policy, self.config.coast_score_decay,
            self._class_options, self._models, self._model_code, self._q_diag,
        )  # fmt: skip
        return self._keep(out[:-1], out[-1] if frame.key_frame else 0, frame.stamp, kalman)

    # ------------------------------------------------------------------ stages
    def _clean(self, frame: Frame) -> Boxes:
        """The frame's boxes without the degenerate ones, in the world frame."""
        boxes = frame.boxes
        keep = drop_degenerate(boxes)
        if keep.size < len(boxes):
            boxes = boxes.take(keep)
        if frame.pose is not None:
            boxes = transform_boxes(boxes, frame.pose)
        return boxes

    def _preprocess(self, frame: Frame) -> Boxes:
        boxes = self._clean(frame)
        return boxes.take(
            nms(
                boxes,
                self._nms_iou,
                vertical=self.config.vertical_overlap,
                tie_order=self.config.tie_order,
            )
        )

    def _predict(self, tr: TrackTable, stamp: float) -> tuple[F64, F64]:
        dt = stamp - tr.t_update
        if self.config.motion is not MotionModel.KALMAN:
            return self._cv.predict(tr.x, dt), tr.p
        if self._models:
            return predict_models(tr.x, tr.p, dt, tr.cls, self._model_code, self._q_diag)
        return self._kf.predict(tr.x, tr.p, dt)

    def _distance_table(
        self,
        d_params: F64,
        d_cls: npt.NDArray[np.int32],
        t_cls: npt.NDArray[np.int32],
        pred: F64,
        p_pred: F64,
    ) -> PairTable:
        """(detection, track) distances of same-class pairs, all classes in one call per metric
        (pairs of different classes never match). A class whose block has at most
        ``DENSE_CELLS`` pairs lists every pair, as the dense assignment needs; a larger one
        lists only the pairs the exact gate (core/gate.py) cannot rule out for either stage,
        so its cost grows with the pairs near each other, not with their product."""
        n_cls = len(self.config.classes)
        per_det = np.bincount(d_cls, minlength=n_cls)
        per_trk = np.bincount(t_cls, minlength=n_cls)
        dense = per_det * per_trk <= DENSE_CELLS
        if dense.all() and d_cls.size * t_cls.size <= 4 * DENSE_CELLS:
            return PairTable.empty(
                dense, matrix=self._dense_table(d_params, d_cls, t_cls, pred, p_pred)
            )
        rows: list[I64] = []
        cols: list[I64] = []
        for code in np.flatnonzero(dense & (per_det > 0) & (per_trk > 0)).tolist():
            di, ti = np.flatnonzero(d_cls == code), np.flatnonzero(t_cls == code)
            rows.append(np.repeat(di, ti.size))
            cols.append(np.tile(ti, di.size))
        det_sparse, trk_sparse = ~dense[d_cls], ~dense[t_cls]
        if det_sparse.any() and trk_sparse.any():
            di, ti = np.flatnonzero(det_sparse), np.flatnonzero(trk_sparse)
            s_gated = self._kf.innovation(p_pred[ti])
            for m in np.unique(self._metric_code[d_cls[di]]).tolist():
                metric = _METRICS[m]
                dm = di[self._metric_code[d_cls[di]] == m]
                ia, ib = gate.association_pairs(
                    metric,
                    d_params[dm],
                    d_cls[dm].astype(np.int64),
                    pred[ti],
                    t_cls[ti].astype(np.int64),
                    self._gate_distance,
                    vertical=self.config.vertical_overlap,
                    innovation=s_gated if metric is Metric.MAHALANOBIS else None,
                )
                rows.append(dm[ia])
                cols.append(ti[ib])
        if not rows:
            return PairTable.empty(dense)
        r, c = np.concatenate(rows), np.concatenate(cols)
        order = np.argsort(r * max(t_cls.size, 1) + c, kind="stable")
        r, c = r[order], c[order]
        dist = np.empty(r.size)
        pair_metric = self._metric_code[d_cls[r]]
        for m in np.unique(pair_metric).tolist():
            metric = _METRICS[m]
            sel = np.flatnonzero(pair_metric == m)
            innovation = self._kf.innovation(p_pred) if metric is Metric.MAHALANOBIS else None
            dist[sel] = geometry.distance_pairs(
                metric,
                d_params,
                pred,
                r[sel],
                c[sel],
                vertical=self.config.vertical_overlap,
                innovation=innovation,
            )
        return PairTable(rows=r, cols=c, dist=dist, dense=dense)

    def _dense_table(
        self,
        d_params: F64,
        d_cls: npt.NDArray[np.int32],
        t_cls: npt.NDArray[np.int32],
        pred: F64,
        p_pred: F64,
    ) -> F64:
        """The ordinary frame's table: every same-class pair, other pairs +inf. The IoU
        family in one compiled walk (core/pair_kernels.py); L2 and Mahalanobis in numpy."""
        exact = self.config.vertical_overlap is VerticalOverlap.EXACT
        d_codes, t_codes = d_cls.astype(np.int64), t_cls.astype(np.int64)
        table = class_table(d_params, d_codes, pred, t_codes, self._overlap_kind, exact)
        if not self._numpy_metric.any():
            return table
        ia, ib = np.nonzero((d_cls[:, None] == t_cls[None, :]) & self._numpy_metric[d_cls][:, None])
        pair_metric = self._metric_code[d_cls[ia]]
        for m in np.unique(pair_metric).tolist():
            metric = _METRICS[m]
            sel = np.flatnonzero(pair_metric == m)
            innovation = self._kf.innovation(p_pred) if metric is Metric.MAHALANOBIS else None
            table[ia[sel], ib[sel]] = geometry.distance_pairs(
                metric,
                d_params,
                pred,
                ia[sel],
                ib[sel],
                vertical=self.config.vertical_overlap,
                innovation=innovation,
            )
        return table

    def _gate_lost(
        self,
        table: PairTable,
        d_params: F64,
        d_cls: npt.NDArray[np.int32],
        t_cls: npt.NDArray[np.int32],
        pred_box: F64,
        p_pred: F64,
        lost: npt.NDArray[np.bool_],
    ) -> PairTable:
        """The table with the lost tracks' pairs that fail their revive_gate at the far cost
        (core/revive_kernels.py)."""
        far = self._far_cost
        gate = self._association[:, REVIVE_GATE]
        if table.matrix is not None:
            matrix = table.matrix.copy()
            gate_dense(
                matrix, d_params, d_cls.astype(np.int64), pred_box, p_pred, lost,
                t_cls.astype(np.int64), self._kf.r, gate, far,
            )  # fmt: skip
            return PairTable.empty(table.dense, matrix=matrix)
        sel = np.flatnonzero(lost[table.cols])
        if sel.size == 0:
            return table
        r, c = table.rows[sel], table.cols[sel]
        ok = gate_pairs(r, c, d_params, pred_box, p_pred, self._kf.r, gate[t_cls[c]])
        dist = table.dist.copy()
        dist[sel[~ok]] = far[t_cls[c[~ok]]]
        return PairTable(rows=table.rows, cols=table.cols, dist=dist, dense=table.dense)

    def _stage1(
        self,
        det_cls: npt.NDArray[np.int32],
        cand: I64,
        cand_rows: I64,
        trk_cls: npt.NDArray[np.int32],
        reach: F64,
        table: PairTable,
    ) -> tuple[I64, I64, I64]:
        """Class by class (a detection never matches a track of another class). A dense class
        is solved on its full block, as it always was; a gated one from its listed pairs.
        ``reach`` is each track's threshold (max_distance unless gate_widening is on)."""
        d_cls = det_cls[cand]
        n_cls = len(self.config.classes)
        present = np.bincount(d_cls, minlength=n_cls) + np.bincount(trk_cls, minlength=n_cls)
        codes = np.flatnonzero(present).astype(np.int64)  # ascending, as np.unique
        if table.matrix is not None:
            md_c, mt_c, um_c, status = stage1_dense(
                table.matrix,
                codes,
                cand,
                cand_rows,
                d_cls.astype(np.int64),
                trk_cls.astype(np.int64),
                self._max_distance,
                self._hungarian,
                self._widened,
                reach,
                self._far_cost,
            )
            if status != INFEASIBLE:
                return md_c, mt_c, um_c
            # A block without a finite full assignment: the Python path raises scipy's error.
        n_rows = int(cand_rows.max(initial=-1)) + 1
        md: list[I64] = []
        mt: list[I64] = []
        um: list[I64] = []
        for code in codes.tolist():
            c = self.config.for_code(code)
            in_class = d_cls == code
            t_idx = np.flatnonzero(trk_cls == code)
            widened = c.gate_widening > 0
            if table.matrix is not None:
                block = table.matrix[np.ix_(cand_rows[in_class], t_idx)]
                if widened:
                    a: Assignment = self._assign_widened(block, reach[t_idx], c, code)
                else:
                    a = assign(block, c.max_distance, c.matcher)
                d_idx = cand[in_class]
                md.append(d_idx[a.det])
                mt.append(t_idx[a.track])
                um.append(d_idx[a.unmatched_dets])
                continue
            # Pool row -> position among the class's candidates; track -> column in its block.
            local_row = np.full(max(n_rows, int(table.rows.max(initial=-1)) + 1), -1, np.int64)
            local_row[cand_rows[in_class]] = np.arange(int(in_class.sum()))
            local_col = np.full(trk_cls.size, -1, dtype=np.int64)
            local_col[t_idx] = np.arange(t_idx.size)
            lr = local_row[table.rows] if table.rows.size else table.rows
            sel = np.flatnonzero((lr >= 0) & (local_col[table.cols] >= 0))
            shape = (int(in_class.sum()), t_idx.size)
            pr, pc, pd = lr[sel], local_col[table.cols[sel]], table.dist[sel]
            if table.dense[code]:
                block = np.full(shape, np.inf)
                block[pr, pc] = pd
                if widened:
                    a = self._assign_widened(block, reach[t_idx], c, code)
                else:
                    a = assign(block, c.max_distance, c.matcher)
            elif widened:
                col_reach = reach[t_idx]
                ok = pd <= col_reach[pc]
                a = assign_pairs(
                    pr[ok],
                    pc[ok],
                    pd[ok],
                    shape,
                    float(col_reach.max(initial=0.0)),
                    c.matcher,
                    self._far_cost[code],
                )
            else:
                a = assign_pairs(pr, pc, pd, shape, c.max_distance, c.matcher, self._far_cost[code])
            d_idx = cand[in_class]
            md.append(d_idx[a.det])
            mt.append(t_idx[a.track])
            um.append(d_idx[a.unmatched_dets])
        empty = np.zeros(0, dtype=np.int64)
        return (
            np.concatenate(md) if md else empty,
            np.concatenate(mt) if mt else empty,
            np.concatenate(um) if um else empty,
        )

    def _stage1_reach(self, tr: TrackTable) -> F64:
        """Each track's stage-1 threshold: max_distance, widened per frame coasted so far
        (time_since_update before this frame, capped at max_age as the gate assumes)."""
        k = np.minimum(tr.time_since_update, self._max_age[tr.cls])
        return np.asarray(
            self._max_distance[tr.cls] + self._gate_widening[tr.cls] * k, dtype=np.float64
        )

    def _assign_widened(self, block: F64, col_reach: F64, c: ClassConfig, code: int) -> Assignment:
        """``assign`` with a threshold per column: a pair over its column's costs the far
        cost (more than any threshold, finite so that the Hungarian solve stays feasible),
        and the solve's rejection at the widest threshold then drops exactly those."""
        masked = np.where(block <= col_reach[None, :], block, self._far_cost[code])
        return assign(masked, float(col_reach.max(initial=0.0)), c.matcher)

    def _stage2(
        self,
        low_rows: I64,
        trk_cls: npt.NDArray[np.int32],
        table: PairTable,
        update: npt.NDArray[np.int8],
        key: bool,
        lost: npt.NDArray[np.bool_],
    ) -> I64:
        """Unmatched tracks that some low-score detection agrees with (any detection over
        ``score_low``, used in stage 1 or not, as the reference does); never a lost one."""
        eligible = (update == UpdateKind.COASTED) & ~lost
        if key:
            eligible &= self._two_stage[trk_cls]
        if table.matrix is not None:
            t_idx = np.flatnonzero(eligible)
            if t_idx.size == 0 or low_rows.size == 0:
                return np.zeros(0, dtype=np.int64)
            near = table.matrix[np.ix_(low_rows, t_idx)] <= self._stage2_max[trk_cls[t_idx]]
            return t_idx[near.any(axis=0)].astype(np.int64)
        if not eligible.any() or low_rows.size == 0 or table.rows.size == 0:
            return np.zeros(0, dtype=np.int64)
        is_low = np.zeros(int(max(low_rows.max(), table.rows.max())) + 1, dtype=bool)
        is_low[low_rows] = True
        r, c = table.rows, table.cols
        near = is_low[r] & eligible[c] & (table.dist <= self._stage2_max[trk_cls[c]])
        return np.unique(c[near]).astype(np.int64)

    def _across_gap(
        self,
        dets: Boxes,
        unmatched_det: I64,
        matched_det: I64,
        matched_trk: I64,
        tr: TrackTable,
        pred_box: F64,
        coasted: npt.NDArray[np.bool_],
        stamp: float,
    ) -> tuple[I64, I64, I64]:
        """Stage-1 matches with the re-associated pairs added, and the detections still
        unmatched (in their order: they are born next). ``coasted``: the tracks that may be
        re-associated (coasting, and not lost: a lost track comes back only under its gate)."""
        left = np.flatnonzero(coasted)
        di, ti = reassociate(
            dets.params[unmatched_det, :2],
            dets.cls[unmatched_det],
            pred_box[left, :2],
            tr.cls[left],
            stamp - tr.t_update[left],
        )
        if di.size == 0:
            return matched_det, matched_trk, unmatched_det
        still = np.ones(unmatched_det.size, dtype=bool)
        still[di] = False
        return (
            np.concatenate([matched_det, unmatched_det[di]]),
            np.concatenate([matched_trk, left[ti]]),
            unmatched_det[still],
        )

    def _advance(
        self,
        tr: TrackTable,
        x_pred: F64,
        p_pred: F64,
        pred_box: F64,
        update: npt.NDArray[np.int8],
        matched_det: I64,
        matched_trk: I64,
        extended: I64,
        unmatched_det: I64,
        dets: Boxes,
        key: bool,
        stamp: float,
    ) -> Tracks:
        """Corrections, scores, life cycle, births, deaths and the output policy, in one
        compiled call (core/advance_kernels.py); the tracks after this frame are kept."""
        kalman = self.config.motion is MotionModel.KALMAN
        velocity = dets.velocity
        out = advance(
            *tr.step_columns(),
            x_pred, p_pred, pred_box, update,
            matched_det, matched_trk, extended, unmatched_det,
            dets.params, dets.score, dets.cls, _NO_VELOCITY if velocity is None else velocity,
            key, kalman, velocity is not None, self._policy, self.frame_count, self.next_id,
            float(stamp), self.config.coast_score_decay,
            self._class_options, self._kf.r, self._p0,
        )  # fmt: skip
        return self._keep(out, int(unmatched_det.size) if key else 0, stamp, kalman)

    def _keep(
        self, out: Sequence[npt.NDArray[Any]], born: int, stamp: float, kalman: bool
    ) -> Tracks:
        """Keep the track table ``advance`` returned (its first 14 outputs); the reported
        tracks from the other 13."""
        (
            t_ids,
            t_cls,
            t_x,
            t_p,
            t_update,
            t_score,
            t_hits,
            t_age,
            t_tsu,
            t_state,
            t_upd,
            t_box,
            t_match,
            t_birth,
            ids,
            box,
            score,
            cls,
            vel,
            state,
            upd,
            hits,
            age,
            tsu,
            cov,
            age_s,
            tsu_s,
        ) = out
        self.tracks = TrackTable(
            t_ids, t_cls, t_x, t_p, t_update, t_score, t_hits, t_age, t_tsu, t_state, t_upd,
            t_box, t_match, t_birth,
        )  # fmt: skip
        self.next_id += born
        self.last_stamp = stamp
        return Tracks(
            ids=ids,
            boxes=Boxes(params=box, score=score, cls=cls),
            velocity=vel,
            state=state,
            update=upd,
            hits=hits,
            age=age,
            time_since_update=tsu,
            covariance=cov if kalman else None,
            age_s=age_s,
            time_since_update_s=tsu_s,
        )

    # ------------------------------------------------------------------ persistence
    def to_bytes(self, state_format: int = STATE_FORMAT) -> bytes:
        """Everything needed to continue exactly where this tracker is, in ``state_format``
        (one of ``STATE_FORMATS``: 1 for readers from before format 2)."""
        if state_format not in STATE_FORMATS:
            raise ValueError(f"state_format must be one of {STATE_FORMATS}: {state_format!r}")
        return pack(
            {
                "format": state_format,
                "config": self.config.model_dump_json(),
                "frame_count": self.frame_count,
                "next_id": self.next_id,
                "last_stamp": self.last_stamp,
                "tracks": self.tracks.to_msgpack_obj(compact=state_format >= 2),
            }
        )

    @classmethod
    def from_bytes(cls, blob: bytes) -> Tracker:
        obj = unpack(blob)
        if obj.get("format") not in STATE_FORMATS:
            raise ValueError(f"unsupported tracker state format {obj.get('format')!r}")
        tracker = cls(TrackerConfig.model_validate_json(obj["config"]))
        tracker.frame_count = int(obj["frame_count"])
        tracker.next_id = int(obj["next_id"])
        tracker.last_stamp = None if obj["last_stamp"] is None else float(obj["last_stamp"])
        tracker.tracks = TrackTable.from_msgpack_obj(obj["tracks"])
        return tracker


def _overlap_kind(metric: Metric) -> int:
    """How core/pair_kernels.py reads a class's metric (NOT_OVERLAP: computed in numpy)."""
    if metric in (Metric.L2, Metric.MAHALANOBIS):
        return NOT_OVERLAP
    return overlap_kind(*geometry.overlap_flags(metric))


def _writable(a: npt.NDArray[Any]) -> npt.NDArray[Any]:
    """``a``, or a copy where it is read-only (decoded straight from a buffer): the compiled
    step is typed for writable arrays (what the staged path's copies always were)."""
    return a if a.flags.writeable else a.copy()


def _or(value: float | None, off: float) -> float:
    return off if value is None else value


__all__ = ["YAW", "Tracker"]
