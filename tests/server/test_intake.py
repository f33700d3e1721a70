"""The worker queue on its own (no Zenoh): lanes served in turn, the fullest lane sheds, every
shed frame is named by a notice, and queries are bounded and take turns with frames; with a
burst budget, recovered frames are kept beyond the queue and served in order, a flood sheds
only fresh frames, and a spent budget refuses catch-up frames as missed."""

from __future__ import annotations

import threading
import time
from collections.abc import Sequence

import pytest

from simpletrack.server.intake import (
    FRAME_OVERHEAD,
    BurstBudget,
    Dropped,
    Inbound,
    Intake,
    Kind,
    WorkQueue,
)
from simpletrack.server.settings import Backpressure
from simpletrack.wire.codec import pack
from simpletrack.wire.header import peek_header
from simpletrack.wire.messages import MAX_NOTICE_SEQS
from simpletrack.wire.reasons import ErrorReason


def frame(key: str, seq: int | None) -> Inbound:
    payload = b"\xc1 garbage" if seq is None else pack({"seq": seq, "stamp_ns": 1000 + seq})
    return Inbound(key, payload, time.time_ns(), time.perf_counter())


def drain(q: WorkQueue) -> list[object]:
    out = []
    while (item := q.get(timeout=0)) is not None:
        out.append(item)
    return out


def test_lanes_take_turns_so_a_backlog_waits_behind_itself() -> None:
    q = WorkQueue(maxsize=100)
    for k in range(10):
        q.put_drop_oldest(frame("noisy", k))
    q.put_drop_oldest(frame("calm", 0))
    keys = [item.key for item in drain(q) if isinstance(item, Inbound)]
    assert keys[:2] == ["noisy", "calm"]  # one noisy frame at most before the calm one
    assert keys.count("noisy") == 10 and len(q) == 0


def test_a_full_queue_sheds_from_the_sensor_holding_the_most() -> None:
    q = WorkQueue(maxsize=8)
    q.put_drop_oldest(frame("calm", 0))
    for k in range(50):
        _, evicted = q.put_drop_oldest(frame("noisy", k))
        assert evicted is None or evicted.key == "noisy"
    q.put_drop_oldest(frame("calm", 1))  # the queue is full: the noisy lane still pays
    items = drain(q)
    calm = [i for i in items if isinstance(i, Inbound) and i.key == "calm"]
    assert len(calm) == 2
    notices = [i for i in items if isinstance(i, Dropped)]
    assert {d.key for d in notices} == {"noisy"}


def test_every_shed_frame_is_named_once_by_a_notice_however_many() -> None:
    q = WorkQueue(maxsize=4)
    n = 3 * MAX_NOTICE_SEQS + 10
    shed = 0
    for k in range(n):
        shed += q.put_drop_oldest(frame("flood", k))[1] is not None
    items = drain(q)
    notices = [i for i in items if isinstance(i, Dropped)]
    named = [s for d in notices for s in d.seqs]
    kept = [i for i in items if isinstance(i, Inbound)]
    assert len(named) == shed == n - 4 and len(kept) == 4
    assert named == list(range(n - 4))  # in order, none twice, none missing
    assert all(len(d.seqs) <= MAX_NOTICE_SEQS for d in notices)
    assert all(d.reason is ErrorReason.DROPPED_QUEUE_FULL for d in notices)
    assert notices[0].stamp_ns == 1000  # the first frame's header


def test_a_notice_names_an_unreadable_frame_as_none() -> None:
    q = WorkQueue(maxsize=1)
    q.put_drop_oldest(frame("junk", None))
    q.put_drop_oldest(frame("junk", 5))
    [notice, kept] = drain(q)
    assert isinstance(notice, Dropped) and notice.seqs == [None] and notice.stamp_ns is None
    assert isinstance(kept, Inbound)


def test_queries_are_bounded_and_take_turns_with_frames() -> None:
    q = WorkQueue(maxsize=100, max_control=3)
    ran: list[int] = []
    accepted = [q.put_control(lambda i=i: ran.append(i)) for i in range(5)]  # type: ignore[misc]
    assert accepted == [True, True, True, False, False]
    for k in range(3):
        q.put_drop_oldest(frame("calm", k))
    order = []
    for item in drain(q):
        if isinstance(item, Inbound):
            order.append("frame")
        else:
            assert callable(item)
            item()
            order.append("query")
    assert order == ["query", "frame", "query", "frame", "query", "frame"]
    assert ran == [0, 1, 2]


def test_close_still_hands_out_what_is_queued_then_stops() -> None:
    q = WorkQueue(maxsize=2)
    for k in range(3):
        q.put_drop_oldest(frame("s", k))
    q.close()
    assert q.put_drop_oldest(frame("s", 9)) == (False, None)
    assert len(drain(q)) == 3  # one notice, two frames
    assert q.get(timeout=1.0) is None and q.closed


def test_a_blocked_producer_resumes_when_the_worker_takes_a_frame() -> None:
    q = WorkQueue(maxsize=1)
    assert q.put_blocking(frame("s", 0))
    done = threading.Event()
    t = threading.Thread(target=lambda: (q.put_blocking(frame("s", 1)), done.set()))
    t.start()
    assert not done.wait(0.1)
    assert isinstance(q.get(timeout=1.0), Inbound)
    assert done.wait(2.0)
    t.join()


# --- checkpoints: a standby's burst of states never sheds a frame -------------------------


def checkpoint(sensor: int, version: int) -> Inbound:
    key = f"bench/@simpletrack/checkpoint/v0/s{sensor}"
    return Inbound(key, pack({"v": version}), time.time_ns(), time.perf_counter(), Kind.CHECKPOINT)


@pytest.mark.parametrize("policy", ["drop_oldest", "block"])
def test_an_owner_s_burst_of_checkpoints_sheds_no_frame_and_waits_for_no_room(
    policy: str,
) -> None:
    # An owner sends every changed sensor's state at once: 300 into a queue of 8 holding
    # this member's own frames. Before: the burst evicted the frames (and checkpoints).
    q = WorkQueue(maxsize=8)
    put = q.put_blocking if policy == "block" else (lambda i: q.put_drop_oldest(i)[0])
    for k in range(8):
        assert put(frame("own", k))
    for sensor in range(300):
        assert put(checkpoint(sensor, 1))  # a full queue: block mode would wait here
    items = drain(q)
    assert not [i for i in items if isinstance(i, Dropped)]
    assert frames_of(items, "own") == list(range(8))
    assert len([i for i in items if isinstance(i, Inbound) and i.kind is Kind.CHECKPOINT]) == 300
    assert len(q) == 0 and q.checkpoints == 0


def test_a_newer_checkpoint_replaces_the_waiting_one_so_one_per_sensor_waits() -> None:
    q = WorkQueue(maxsize=4)
    for version in range(5):
        for sensor in range(3):
            q.put_drop_oldest(checkpoint(sensor, version))
    assert q.checkpoints == 3 and len(q) == 0  # frames only
    q.put_drop_oldest(frame("own", 0))
    items = drain(q)
    states = [i.payload for i in items if isinstance(i, Inbound) and i.kind is Kind.CHECKPOINT]
    assert states == [pack({"v": 4})] * 3
    assert frames_of(items, "own") == [0]
    q.close()
    assert q.put_drop_oldest(checkpoint(0, 5)) == (False, None)
    assert not q.put_blocking(checkpoint(0, 5))


def test_of_two_states_of_a_sensor_the_one_written_later_waits_whatever_their_order() -> None:
    q = WorkQueue(maxsize=4)

    def state(written_ns: int) -> Inbound:
        return Inbound("cp/v0/s0", pack({"written_ns": written_ns}), 0, 0.0, Kind.CHECKPOINT)

    for written_ns in (20, 10, 30, 25):  # 10 and 25 overtaken on the way (or a stale member's)
        assert q.put_drop_oldest(state(written_ns)) == (True, None)
    [only] = drain(q)
    assert isinstance(only, Inbound) and only.payload == pack({"written_ns": 30})


def test_checkpoints_of_more_sensors_than_the_bound_are_refused_and_counted() -> None:
    q = WorkQueue(maxsize=4, max_checkpoints=2)
    dropped: list[tuple[str, ErrorReason]] = []
    intake = Intake(
        [q], Backpressure.DROP_OLDEST, lambda key: None, lambda i, r: dropped.append((i.key, r))
    )
    for sensor in (0, 1, 2, 0):
        intake._enqueue("v0/s", checkpoint(sensor, 1))
    assert q.checkpoints == 2  # sensor 0's newer one replaced its own; sensor 2's refused
    assert dropped == [(checkpoint(2, 1).key, ErrorReason.DROPPED_QUEUE_FULL)]
    assert q.put_drop_oldest(frame("own", 0)) == (True, None)  # frames are not bounded by it


# --- catch-up frames: recovered or replayed bursts are kept beyond maxsize, never shed ------

S = 1_000_000_000  # ns
T0 = 1_800_000_000 * S  # the service's clock (received_ns) in these tests


def at(key: str, seq: int, stamp_ns: int, received_ns: int, pad: int = 0) -> Inbound:
    """A frame of ``key`` stamped ``stamp_ns`` that arrives at ``received_ns``."""
    payload = pack({"seq": seq, "stamp_ns": stamp_ns, "pad": b"x" * pad})
    return Inbound(key, payload, received_ns, time.perf_counter())


def cost(item: Inbound) -> int:
    return len(item.payload) + FRAME_OVERHEAD


def recovered_burst(key: str, first: int, n: int, now: int, tail: int = 0) -> list[Inbound]:
    """A 10 Hz sensor's frames ``first``..: ``n`` published during an outage that ended 1 s
    ago and ``tail`` published as the link came back, all arriving at ``now``."""
    frames = [at(key, first + k, now - S - (n - k) * S // 10, now) for k in range(n)]
    return frames + [at(key, first + n + k, now - S // 100, now) for k in range(tail)]


def frames_of(items: Sequence[object], key: str) -> list[int]:
    return [
        int(peek_header(i.payload)[0] or 0)
        for i in items
        if isinstance(i, Inbound) and i.key == key
    ]


def test_a_catch_up_burst_ten_times_the_queue_is_kept_and_served_in_order() -> None:
    budget = BurstBudget(1 << 20)
    q = WorkQueue(maxsize=8, budget=budget)
    # Its usual delay: 5 ms (a sensor's first frames teach it; it is never the service's clock).
    for k in range(3):
        assert q.put_drop_oldest(at("veh/lidar", k, T0 + k * S // 10, T0 + k * S // 10 + 5_000_000))
    drain(q)
    burst = recovered_burst("veh/lidar", 3, 80, T0 + 9 * S, tail=6)
    for item in burst:
        assert q.put_drop_oldest(item) == (True, None)  # nothing evicted, nothing refused
    assert len(q) == 86 and q.kept == 86 and budget.kept == 86  # the tail follows the burst
    assert budget.in_use == sum(cost(i) for i in burst)
    items = drain(q)
    assert not [i for i in items if isinstance(i, Dropped)]
    assert frames_of(items, "veh/lidar") == list(range(3, 89))
    assert budget.in_use == 0 and budget.peak == sum(cost(i) for i in burst)


def test_a_fresh_flood_during_a_burst_sheds_only_its_own_fresh_frames() -> None:
    budget = BurstBudget(1 << 20)
    q = WorkQueue(maxsize=8, budget=budget)
    for key in ("veh/lidar", "veh/flood", "veh/calm"):
        q.put_drop_oldest(at(key, 0, T0, T0 + 1_000_000))
    drain(q)
    now = T0 + 9 * S
    burst = recovered_burst("veh/lidar", 1, 80, now, tail=6)
    flood = [at("veh/flood", 1 + k, now + k * 1000, now + k * 1000) for k in range(800)]
    for k, item in enumerate(flood):  # the flood interleaved with the recovered frames
        if k < len(burst):
            assert q.put_drop_oldest(burst[k]) == (True, None)
        accepted, evicted = q.put_drop_oldest(item)
        assert accepted and (evicted is None or evicted.key == "veh/flood")
    _, evicted = q.put_drop_oldest(at("veh/calm", 1, now, now + 1_000_000))
    assert evicted is not None and evicted.key == "veh/flood"  # the flood pays, as before
    items = drain(q)
    assert frames_of(items, "veh/lidar") == list(range(1, 87))  # all of them, in order
    assert frames_of(items, "veh/calm") == [1]
    assert frames_of(items, "veh/flood") == list(range(794, 801))  # maxsize - 1 fresh kept
    notices = [i for i in items if isinstance(i, Dropped)]
    assert {d.key for d in notices} == {"veh/flood"}
    assert all(d.reason is ErrorReason.DROPPED_QUEUE_FULL for d in notices)
    assert [s for d in notices for s in d.seqs] == list(range(1, 794))
    assert budget.in_use == 0


def test_a_spent_budget_refuses_catch_up_frames_as_missed_and_memory_stays_bounded() -> None:
    burst = recovered_burst("veh/lidar", 1, 50, T0 + 9 * S)
    per_frame = cost(burst[0])
    budget = BurstBudget(10 * per_frame)
    q = WorkQueue(maxsize=4, budget=budget)
    q.put_drop_oldest(at("veh/lidar", 0, T0, T0 + 1_000_000))
    drain(q)
    dropped: list[tuple[Inbound, ErrorReason]] = []
    intake = Intake(
        [q], Backpressure.DROP_OLDEST, lambda key: None, lambda i, r: dropped.append((i, r))
    )
    for item in burst:
        intake._enqueue(item.key, item)
        assert budget.in_use <= budget.limit
    assert len(q) == q.kept == 10 and budget.in_use == 10 * per_frame
    assert [r for _, r in dropped] == [ErrorReason.MISSED] * 40  # counted by the service
    items = drain(q)
    assert frames_of(items, "veh/lidar") == list(range(1, 11))
    [notice] = [i for i in items if isinstance(i, Dropped)]  # announced, before its frames
    assert items[0] is notice and notice.reason is ErrorReason.MISSED
    assert notice.seqs == list(range(11, 51))
    assert budget.in_use == 0 and budget.peak == 10 * per_frame


def test_block_mode_keeps_a_burst_on_the_budget_then_waits_past_it_and_loses_nothing() -> None:
    burst = recovered_burst("veh/lidar", 1, 30, T0 + 9 * S)
    budget = BurstBudget(20 * cost(burst[0]))
    q = WorkQueue(maxsize=2, budget=budget)
    q.put_blocking(at("veh/lidar", 0, T0, T0 + 1_000_000))
    drain(q)
    done = threading.Event()

    def produce() -> None:
        for item in burst:
            q.put_blocking(item)
        done.set()

    t = threading.Thread(target=produce)
    t.start()
    assert not done.wait(0.2)  # 20 on the budget, 2 fresh, the 23rd waits for room
    assert len(q) == 22 and q.kept == 20
    items: list[object] = []
    while not done.is_set() or len(q):
        item = q.get(timeout=0.05)
        if item is not None:
            items.append(item)
    t.join()
    assert frames_of(items, "veh/lidar") == list(range(1, 31))
    assert not [i for i in items if isinstance(i, Dropped)] and budget.in_use == 0


def test_a_sensor_is_judged_against_its_own_usual_delay() -> None:
    q = WorkQueue(maxsize=4, budget=BurstBudget(1 << 20))
    # A vehicle clock 5 s behind, and a replayed log stamped in 2023: steady, so fresh.
    for k in range(20):
        now = T0 + k * S // 10
        q.put_drop_oldest(at("slow-clock", k, now - 5 * S, now))
        q.put_drop_oldest(at("old-log", k, 1_700_000_000 * S + k * S // 10, now))
    assert q.kept == 0 and len(q) == 4  # all fresh: the queue shed as before
    # A log replayed faster than it was recorded is a flood, not a catch-up.
    for k in range(20, 200):
        q.put_drop_oldest(at("old-log", k, 1_700_000_000 * S + k * S // 10, T0 + 2 * S + k))
    assert q.kept == 0
    # The slow clock's frames arriving 0.8 s later than usual are behind.
    q.put_drop_oldest(at("slow-clock", 20, T0 + 2 * S - 5 * S, T0 + 2 * S + 800_000_000))
    assert q.kept == 1


def test_a_sensor_cannot_keep_a_flood_behind_one_catch_up_frame() -> None:
    q = WorkQueue(maxsize=4, budget=BurstBudget(1 << 20))
    q.put_drop_oldest(at("s", 0, T0, T0))
    drain(q)
    q.put_drop_oldest(at("s", 1, T0 + 1 * S, T0 + 5 * S))  # behind
    for k in range(2, 100):  # then a flood of fresh frames
        q.put_drop_oldest(at("s", k, T0 + 5 * S + k, T0 + 5 * S + k))
    assert q.kept == 1 + 4 and len(q) == 1 + 4 + 4  # 4 follow it, 4 fresh, the rest shed


def test_the_burst_budget_is_shared_safely_and_never_passes_its_limit() -> None:
    budget = BurstBudget(1000)
    assert budget.take(600) and not budget.take(500) and budget.take(400)
    assert budget.in_use == budget.peak == 1000
    budget.give(1000)
    errors = []

    def churn() -> None:
        for _ in range(5000):
            if budget.take(7, kept=True):
                if budget.in_use > budget.limit:
                    errors.append(budget.in_use)
                budget.give(7)

    threads = [threading.Thread(target=churn) for _ in range(4)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert not errors and budget.in_use == 0 and budget.peak <= 1000 and budget.kept <= 20000
    with pytest.raises(ValueError):
        budget.give(1)
