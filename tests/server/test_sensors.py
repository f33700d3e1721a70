"""The per-sensor ordering rules as a table, and the sensor state they act on: no Zenoh, no
threads."""

from __future__ import annotations

import numpy as np
import pytest

from simpletrack.core.boxes import Boxes
from simpletrack.core.config import preset
from simpletrack.core.frames import Frame
from simpletrack.core.tracker import Tracker
from simpletrack.server.sensors import (
    Order,
    OrderRules,
    SensorBudget,
    SensorState,
    check_order,
)
from simpletrack.wire.reasons import ErrorReason

S = 1_000_000_000  # one second in ns
T = 1_700_000_000 * S  # the sensor's last tracked stamp
RULES = OrderRules(reset_gap_s=5.0, reset_backward_s=5.0)
REFUSED = {Order.DUPLICATE_SEQ, Order.OUT_OF_ORDER, Order.SEQ_NOT_INCREASING}

# (last_seq, last_stamp_ns) of the sensor, (seq, stamp_ns) of the frame -> what happens.
ORDER_TABLE = [
    pytest.param(None, None, 0, T, Order.TRACK, id="first frame: nothing to check against"),
    pytest.param(7, None, 3, T, Order.TRACK, id="no last stamp (after a failed step): track"),
    pytest.param(None, T, 3, T, Order.TRACK, id="no last seq: track"),
    pytest.param(5, T, 6, T + S // 10, Order.TRACK, id="next seq, later stamp"),
    pytest.param(5, T, 9, T + S // 2, Order.TRACK, id="seq skips ahead (frames lost)"),
    pytest.param(5, T, 6, T + 1, Order.TRACK, id="stamp one ns later"),
    pytest.param(5, T, 6, T + 5 * S, Order.TRACK, id="stamp exactly reset_gap_s ahead: no reset"),
    pytest.param(5, T, 6, T + 5 * S + 1, Order.RESET_GAP, id="stamp over reset_gap_s ahead"),
    pytest.param(5, T, 500, T + 60 * S, Order.RESET_GAP, id="long silence, seq far ahead"),
    pytest.param(5, T, 5, T + S // 10, Order.DUPLICATE_SEQ, id="duplicate seq"),
    pytest.param(5, T, 5, T, Order.DUPLICATE_SEQ, id="the same frame again"),
    pytest.param(
        5, T, 5, T - 60 * S, Order.DUPLICATE_SEQ, id="duplicate seq wins over a time jump back"
    ),
    pytest.param(
        5, T, 5, T + 60 * S, Order.DUPLICATE_SEQ, id="duplicate seq wins over a stamp gap"
    ),
    pytest.param(5, T, 6, T, Order.OUT_OF_ORDER, id="stamp equal to the last"),
    pytest.param(5, T, 6, T - S, Order.OUT_OF_ORDER, id="stamp behind, within reset_backward_s"),
    pytest.param(
        5, T, 6, T - 5 * S, Order.OUT_OF_ORDER, id="stamp exactly reset_backward_s behind"
    ),
    pytest.param(
        5, T, 4, T - S, Order.OUT_OF_ORDER, id="seq and stamp back a little: stamp checked first"
    ),
    pytest.param(
        5, T, 6, T - 5 * S - 1, Order.RESET_TIME_BACKWARDS, id="stamp over reset_backward_s behind"
    ),
    pytest.param(
        100, T, 0, T - 60 * S, Order.RESET_TIME_BACKWARDS, id="replay restarted: seq and stamp back"
    ),
    pytest.param(5, T, 4, T + S // 10, Order.SEQ_NOT_INCREASING, id="seq back, stamp forward"),
    pytest.param(
        5, T, 0, T + 60 * S, Order.SEQ_NOT_INCREASING, id="seq back wins over a stamp gap"
    ),
]


@pytest.mark.parametrize(("last_seq", "last_stamp", "seq", "stamp", "expected"), ORDER_TABLE)
def test_ordering_rule(
    last_seq: int | None, last_stamp: int | None, seq: int, stamp: int, expected: Order
) -> None:
    assert check_order(last_seq, last_stamp, seq, stamp, RULES).order is expected


def test_refusals_carry_their_wire_reason_field_and_detail() -> None:
    dup = check_order(5, T, 5, T + 1, RULES)
    assert (dup.reason, dup.field, dup.detail) == (
        ErrorReason.DUPLICATE_SEQ,
        "seq",
        "seq 5 was already processed",
    )
    late = check_order(5, T, 6, T - 1, RULES)
    assert (late.reason, late.field, late.detail) == (
        ErrorReason.OUT_OF_ORDER,
        "stamp_ns",
        f"stamp_ns {T - 1} is not after the last processed {T}",
    )
    back = check_order(5, T, 4, T + 1, RULES)
    assert (back.reason, back.field, back.detail) == (
        ErrorReason.SEQ_NOT_INCREASING,
        "seq",
        "seq 4 is below the last processed 5",
    )


@pytest.mark.parametrize(("last_seq", "last_stamp", "seq", "stamp", "expected"), ORDER_TABLE)
def test_refused_frames_name_their_wire_reason_and_the_others_none(
    last_seq: int | None, last_stamp: int | None, seq: int, stamp: int, expected: Order
) -> None:
    verdict = check_order(last_seq, last_stamp, seq, stamp, RULES)
    if expected in REFUSED:
        assert verdict.reason is ErrorReason(expected.value) and verdict.field is not None
    else:
        assert verdict.reason is None and verdict.order.resets == (expected is not Order.TRACK)


def test_reset_labels_are_the_metric_reasons() -> None:
    assert {Order.RESET_GAP.value, Order.RESET_TIME_BACKWARDS.value} == {"gap", "time_backwards"}


def test_thresholds_come_from_the_rules() -> None:
    tight = OrderRules(reset_gap_s=0.5, reset_backward_s=0.25)
    assert check_order(5, T, 6, T + S, tight).order is Order.RESET_GAP
    assert check_order(5, T, 6, T + S, RULES).order is Order.TRACK
    assert check_order(5, T, 6, T - S // 2, tight).order is Order.RESET_TIME_BACKWARDS
    assert check_order(5, T, 6, T - S // 2, RULES).order is Order.OUT_OF_ORDER


# ------------------------------------------------------------------------------ sensor state
def _cars(n: int, x: float) -> Boxes:
    params = np.array([[x, 5.0 * i, 0.8, 0.0, 4.0, 2.0, 1.6] for i in range(n)]).reshape(-1, 7)
    return Boxes.from_arrays(params, np.full(n, 0.9), np.zeros(n, np.int64))


def _state() -> SensorState:
    return SensorState("car-1", "lidar", Tracker(preset("kitti")), id_base=10)


def test_tracker_time_counts_from_the_first_stamp() -> None:
    s = _state()
    assert s.tracker_stamp(T) == 0.0
    assert s.tracker_stamp(T + S // 2) == pytest.approx(0.5)
    assert s.stamp_origin_ns == T


def test_a_tracked_frame_moves_the_last_seq_and_stamp() -> None:
    s = _state()
    s.dirty = False
    assert s.tracked(3, T, active_tracks=4) == 4
    assert s.tracked(4, T + S, active_tracks=1) == -3
    assert (s.last_seq, s.last_stamp_ns, s.frames, s.active_tracks, s.dirty) == (
        4,
        T + S,
        2,
        1,
        True,
    )


def test_a_reset_starts_ids_above_every_id_given_and_forgets_the_last_frame() -> None:
    s = _state()
    s.tracker.step(Frame(boxes=_cars(3, 0.0), stamp=s.tracker_stamp(T)))
    s.tracked(1, T, active_tracks=3)
    assert s.id_next == 13
    s.reset(T + 60 * S)
    assert (s.id_base, s.id_next) == (13, 13)
    assert (s.last_seq, s.last_stamp_ns, s.active_tracks) == (None, None, 0)
    assert s.tracker_stamp(T + 60 * S) == 0.0  # the tracker's clock restarts at the reset
    assert check_order(s.last_seq, s.last_stamp_ns, 0, T + 60 * S, RULES).order is Order.TRACK


def test_snapshot_without_tracker_reserves_the_ids() -> None:
    s = _state()
    s.tracker.step(Frame(boxes=_cars(2, 0.0), stamp=0.0))
    full, reservation = s.snapshot("d"), s.snapshot("d", with_tracker=False)
    assert full.tracker is not None and (full.id_base, full.id_next) == (10, 12)
    assert reservation.tracker is None and (reservation.id_base, reservation.id_next) == (12, 12)


def test_the_budget_refuses_past_its_limit_and_frees_on_release() -> None:
    b = SensorBudget(2)
    assert [b.acquire(), b.acquire(), b.acquire()] == [True, True, False]
    b.release()
    assert b.acquire() and b.used == 2
