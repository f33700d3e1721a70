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
    RESETS,
    Arrival,
    Order,
    OrderRules,
    SensorBudget,
    SensorState,
    check_order,
    lead_ns,
    unheard_start,
)
from simpletrack.wire.reasons import ErrorReason

S = 1_000_000_000  # one second in ns
T = 1_700_000_000 * S  # the sensor's last tracked stamp
W = 1_800_000_000 * S  # the service's wall clock when that frame arrived
RULES = OrderRules(reset_gap_s=5.0, reset_backward_s=5.0)
REFUSED = {Order.DUPLICATE_SEQ, Order.OUT_OF_ORDER}
A, B = 11, 22  # two publisher sessions


def at(seq: int, stamp: int, wall: int | None = None, session: int | None = None) -> Arrival:
    """A frame of ``seq`` stamped ``stamp`` received ``wall`` ns after W (None: unknown)."""
    return Arrival(seq, stamp, None if wall is None else W + wall, session)


LAST = at(5, T, 0)
# The sensor's last tracked frame, the frame -> what happens. Frames arrive 0.1 s after the
# last one unless the row says otherwise.
ORDER_TABLE = [
    pytest.param(None, at(0, T), Order.TRACK, id="first frame: nothing to check against"),
    pytest.param(LAST, at(6, T + S // 10, S // 10), Order.TRACK, id="next seq, later stamp"),
    pytest.param(LAST, at(9, T + S // 2, S // 2), Order.TRACK, id="seq skips ahead (lost frames)"),
    pytest.param(LAST, at(6, T + 1, S // 10), Order.TRACK, id="stamp one ns later"),
    pytest.param(
        LAST, at(6, T + 5 * S, S // 10), Order.TRACK, id="stamp exactly reset_gap_s ahead"
    ),
    pytest.param(LAST, at(6, T + 6 * S, S // 10), Order.RESET_GAP, id="sensor clock jumps 6 s"),
    pytest.param(
        LAST, at(6, T + 5 * S + S // 10, S // 10), Order.BRIDGE_GAP, id="lead exactly reset_gap_s"
    ),
    pytest.param(
        LAST, at(6, T + 5 * S + S // 10 + 1, S // 10), Order.RESET_GAP, id="lead over reset_gap_s"
    ),
    pytest.param(
        LAST, at(6, T + 5 * S + 1), Order.RESET_GAP, id="over reset_gap_s, receipt unknown"
    ),
    pytest.param(
        LAST, at(500, T + 60 * S, 60 * S), Order.BRIDGE_GAP, id="an outage: 60 s on both clocks"
    ),
    pytest.param(
        LAST, at(6, T + 60 * S, 56 * S), Order.BRIDGE_GAP, id="outage, clocks 4 s apart: bridged"
    ),
    pytest.param(
        LAST, at(6, T + 60 * S, 54 * S), Order.RESET_GAP, id="outage and a 6 s jump: reset"
    ),
    pytest.param(
        LAST, at(6, T + 10 * S, 30 * S), Order.BRIDGE_GAP, id="stamps behind the wall clock"
    ),
    pytest.param(LAST, at(5, T, S // 10), Order.DUPLICATE_SEQ, id="the same frame again"),
    pytest.param(LAST, at(5, T - S, S // 10), Order.DUPLICATE_SEQ, id="same seq, earlier stamp"),
    pytest.param(
        LAST, at(5, T - 60 * S), Order.DUPLICATE_SEQ, id="duplicate seq wins over a jump back"
    ),
    pytest.param(LAST, at(5, T + S // 10, S // 10), Order.TRACK, id="same seq, later stamp"),
    pytest.param(LAST, at(6, T, S // 10), Order.OUT_OF_ORDER, id="stamp equal to the last"),
    pytest.param(LAST, at(6, T - S, S // 10), Order.OUT_OF_ORDER, id="stamp behind a little"),
    pytest.param(
        LAST, at(6, T - 5 * S), Order.OUT_OF_ORDER, id="stamp exactly reset_backward_s behind"
    ),
    pytest.param(
        LAST, at(6, T - 5 * S - 1), Order.RESET_TIME_BACKWARDS, id="over reset_backward_s behind"
    ),
    pytest.param(at(100, T), at(0, T - 60 * S), Order.RESET_TIME_BACKWARDS, id="replay restarted"),
    pytest.param(LAST, at(4, T + S // 10, S // 10), Order.TRACK, id="seq back, stamp forward"),
    pytest.param(LAST, at(0, T + S // 10, S // 10), Order.TRACK, id="seq restarted at 0"),
    pytest.param(
        at(2**62, T, 0), at(6, T + S // 10, S // 10), Order.TRACK, id="after a spoofed seq 2^62"
    ),
    pytest.param(
        at(5, T, 0, A), at(0, T + S // 10, S // 10, B), Order.TRACK, id="new session, later"
    ),
    pytest.param(
        at(5, T, 0, A), at(0, T - S, S // 10, B), Order.RESET_RESTART, id="new session, behind"
    ),
    pytest.param(
        at(5, T, 0, A), at(5, T, S // 10, B), Order.RESET_RESTART, id="new session, same frame"
    ),
    pytest.param(
        at(5, T, 0, None), at(0, T + S, S, B), Order.TRACK, id="a session id appears: later"
    ),
    pytest.param(
        at(5, T, 0, A), at(9, T + 60 * S, 60 * S, B), Order.BRIDGE_GAP, id="reboot in 60 s"
    ),
]


@pytest.mark.parametrize(("last", "frame", "expected"), ORDER_TABLE)
def test_ordering_rule(last: Arrival | None, frame: Arrival, expected: Order) -> None:
    assert check_order(last, frame, RULES).order is expected


# (the frame before the last, the last, the frame) -> what happens; W + wall is the receipt.
BEFORE = at(4, T - S // 10, -(S // 10), A)
UNDO_TABLE = [
    pytest.param(
        BEFORE,
        at(5, T + 3 * S, 0, A),
        at(5, T + S // 10, S // 10, A),
        Order.UNDO_LAST,
        id="last 3 s ahead of the wall clock, frame on time: undo",
    ),
    pytest.param(
        BEFORE,
        at(5, T + 3600 * S, 0, A),
        at(5, T + S // 10, S // 10, A),
        Order.UNDO_LAST,
        id="last an hour ahead (it reset), frame on time: undo, not a second reset",
    ),
    pytest.param(
        BEFORE,
        at(5, T - 3600 * S, 0, A),
        at(5, T + S // 10, S // 10, A),
        Order.UNDO_LAST,
        id="last an hour behind (it reset), frame on time: undo",
    ),
    pytest.param(
        BEFORE,
        at(5, T - S // 20, 0, B),
        at(5, T + S // 10, S // 10, A),
        Order.UNDO_LAST,
        id="last of a stray session between two of ours: undo",
    ),
    pytest.param(
        BEFORE,
        at(5, T, 0, A),
        at(6, T - S // 20, S // 10, A),
        Order.OUT_OF_ORDER,
        id="last on time, frame late: a reordered frame is refused",
    ),
    pytest.param(
        BEFORE,
        at(5, T + 3 * S, 0, A),
        at(6, T + 3 * S + S // 10, S // 10, A),
        Order.TRACK,
        id="last ahead, frame follows it: nothing to undo",
    ),
    pytest.param(
        BEFORE,
        at(5, T + 3 * S, 0, A),
        at(6, T - S // 5, S // 10, A),
        Order.OUT_OF_ORDER,
        id="frame before the frame before: no undo",
    ),
    pytest.param(
        BEFORE,
        at(5, T + 3 * S, 0, A),
        at(6, T + S // 10, S // 10, B),
        Order.RESET_RESTART,
        id="frame of another session: no undo",
    ),
    pytest.param(
        BEFORE,
        at(5, T + 3 * S, 0, A),
        at(6, T + 2 * S, S // 10, A),
        Order.OUT_OF_ORDER,
        id="frame off the wall clock too: no undo",
    ),
    pytest.param(
        at(4, T - S // 10, None, A),
        at(5, T + 3 * S, 0, A),
        at(6, T + S // 10, S // 10, A),
        Order.OUT_OF_ORDER,
        id="receipt of the frame before unknown: no undo",
    ),
]


@pytest.mark.parametrize(("before", "last", "frame", "expected"), UNDO_TABLE)
def test_undo_rule(before: Arrival, last: Arrival, frame: Arrival, expected: Order) -> None:
    assert check_order(last, frame, RULES, before).order is expected


@pytest.mark.parametrize(
    ("last", "frame", "unheard"),
    [
        (at(40, 4_000, session=1), at(12, 5_000, session=2), True),  # 0-11 reached no one
        (at(40, 4_000, session=1), at(45, 5_000, session=2), True),  # resumed, 41-44 unheard
        (at(40, 4_000, session=1), at(0, 5_000, session=2), False),  # a new numbering's first
        (at(40, 4_000, session=1), at(41, 5_000, session=2), False),  # resumed, nothing lost
        (at(40, 4_000, session=1), at(12, 5_000, session=1), False),  # the same session
        (at(40, 4_000, session=1), at(12, 3_000, session=2), False),  # earlier: order rules
        (at(40, 4_000), at(12, 5_000, session=2), False),  # no session to tell them by
        (at(40, 4_000, session=1), at(12, 5_000), False),
        (None, at(12, 5_000, session=2), False),  # the sensor's first frame
    ],
)
def test_a_restarted_publishers_first_frame_heard_tells_whether_earlier_ones_went_unheard(
    last: Arrival | None, frame: Arrival, unheard: bool
) -> None:
    assert unheard_start(last, frame) is unheard


def test_lead_is_the_stamp_step_minus_the_wall_step() -> None:
    assert lead_ns(at(0, T, 0), at(1, T + 3 * S, S)) == 2 * S
    assert lead_ns(at(0, T), at(1, T + 3 * S, S)) is None


def test_refusals_carry_their_wire_reason_field_and_detail() -> None:
    dup = check_order(LAST, at(5, T - 1), RULES)
    assert (dup.reason, dup.field, dup.detail) == (
        ErrorReason.DUPLICATE_SEQ,
        "seq",
        "seq 5 was already processed",
    )
    late = check_order(LAST, at(6, T - 1), RULES)
    assert (late.reason, late.field, late.detail) == (
        ErrorReason.OUT_OF_ORDER,
        "stamp_ns",
        f"stamp_ns {T - 1} is not after the last processed {T}",
    )


@pytest.mark.parametrize(("last", "frame", "expected"), ORDER_TABLE)
def test_refused_frames_name_their_wire_reason_and_the_others_none(
    last: Arrival | None, frame: Arrival, expected: Order
) -> None:
    verdict = check_order(last, frame, RULES)
    if expected in REFUSED:
        assert verdict.reason is ErrorReason(expected.value) and verdict.field is not None
    else:
        assert verdict.reason is None and verdict.order.resets == (expected in RESETS)


def test_reset_labels_are_the_metric_reasons() -> None:
    assert {o.value for o in RESETS} == {"gap", "time_backwards", "restart"}


def test_thresholds_come_from_the_rules() -> None:
    tight = OrderRules(reset_gap_s=0.5, reset_backward_s=0.25)
    assert check_order(LAST, at(6, T + S), tight).order is Order.RESET_GAP
    assert check_order(LAST, at(6, T + S), RULES).order is Order.TRACK
    assert check_order(LAST, at(6, T - S // 2), tight).order is Order.RESET_TIME_BACKWARDS
    assert check_order(LAST, at(6, T - S // 2), RULES).order is Order.OUT_OF_ORDER


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
    assert s.tracked(at(3, T), active_tracks=4) == 4
    assert s.tracked(at(4, T + S), active_tracks=1) == -3
    assert (s.last_seq, s.last_stamp_ns, s.frames, s.active_tracks, s.dirty) == (
        4,
        T + S,
        2,
        1,
        True,
    )


def test_a_reset_starts_ids_above_every_id_given_and_restarts_the_tracker_clock() -> None:
    s = _state()
    s.tracker.step(Frame(boxes=_cars(3, 0.0), stamp=s.tracker_stamp(T)))
    s.tracked(at(1, T), active_tracks=3)
    assert s.id_next == 13
    s.reset(T + 60 * S)
    assert (s.id_base, s.id_next, s.active_tracks) == (13, 13, 0)
    assert s.tracker_stamp(T + 60 * S) == 0.0  # the tracker's clock restarts at the reset


def test_undo_puts_the_tracks_back_and_keeps_the_ids_of_the_undone_frame_used() -> None:
    s = _state()
    s.keep_undo()
    s.tracker.step(Frame(boxes=_cars(3, 0.0), stamp=s.tracker_stamp(T)))
    s.tracked(at(1, T, 0), active_tracks=3)
    tracks_before = s.tracker.tracks
    s.keep_undo()
    s.reset(T + 3600 * S)  # a stray frame an hour ahead: reset, two new tracks
    s.tracker.step(Frame(boxes=_cars(2, 50.0), stamp=s.tracker_stamp(T + 3600 * S)))
    s.tracked(at(2, T + 3600 * S, S // 10), active_tracks=2)
    assert s.id_next == 15
    assert s.undo_last() == 1
    assert s.tracker.tracks is tracks_before and s.last == at(1, T, 0) and s.before is None
    assert (s.id_base, s.stamp_origin_ns, s.active_tracks) == (10, T, 3)
    assert s.id_next == 15  # ids 13 and 14 went out on the undone frame: never again
    with pytest.raises(RuntimeError):
        s.undo_last()


def test_snapshot_without_tracker_reserves_the_ids() -> None:
    s = _state()
    s.tracker.step(Frame(boxes=_cars(2, 0.0), stamp=0.0))
    full = s.snapshot("d", state_format=2)
    reservation = s.snapshot("d", with_tracker=False, state_format=2)
    assert full.tracker is not None and (full.id_base, full.id_next) == (10, 12)
    assert reservation.tracker is None and (reservation.id_base, reservation.id_next) == (12, 12)


def test_the_budget_refuses_past_its_limit_and_frees_on_release() -> None:
    b = SensorBudget(2)
    assert [b.acquire(), b.acquire(), b.acquire()] == [True, True, False]
    b.release()
    assert b.acquire() and b.used == 2
