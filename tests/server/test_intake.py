"""The worker queue on its own (no Zenoh): lanes served in turn, the fullest lane sheds, every
shed frame is named by a notice, and queries are bounded and take turns with frames."""

from __future__ import annotations

import threading
import time

from simpletrack.server.intake import Dropped, Inbound, WorkQueue
from simpletrack.wire.codec import pack
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
