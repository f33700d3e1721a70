"""What a member heard on its streams' tracks keys (server/heard.py): read in batches, yet
whoever looks sees every message that had come, merged as one at a time would have."""

from __future__ import annotations

import threading
from typing import Any

import msgpack
import numpy as np
import pytest

from simpletrack.server import heard as heard_module
from simpletrack.server.heard import HeardStreams
from simpletrack.wire import generate
from tests.server.fake_clock import Clock

OWN = msgpack.packb("instance") + msgpack.packb("member-b")


def message(stamp_ns: int, ids: list[int], epoch: int | None = 3, instance: str = "a") -> bytes:
    """A tracks message (schema 3) with these stamp, ids and epoch, from ``instance``."""
    obj: dict[str, Any] = msgpack.unpackb(generate._tracks(3, epoch=epoch or 1), raw=False)
    obj["stamp_ns"], obj["instance"] = stamp_ns, instance
    if epoch is None:
        del obj["epoch"]
    tracks = obj["tracks"]
    n = len(ids)
    for name, column in list(tracks.items()):
        if isinstance(column, bytes) and tracks["count"]:
            width = len(column) // tracks["count"]
            tracks[name] = (column[:width] * n) if n else b""
    tracks["count"], tracks["id"] = n, np.array(ids, dtype="<i8").tobytes()
    return msgpack.packb(obj)


@pytest.fixture
def reads(monkeypatch: pytest.MonkeyPatch) -> list[bytes]:
    """Every payload read, in the order read."""
    seen: list[bytes] = []
    peek = heard_module.peek_heard

    def counted(payload: bytes) -> tuple[int, int, int | None] | None:
        seen.append(payload)
        return peek(payload)

    monkeypatch.setattr(heard_module, "peek_heard", counted)
    return seen


def test_whoever_looks_sees_every_message_that_came_before(reads: list[bytes]) -> None:
    clock = Clock()
    heard = HeardStreams(OWN, batch=64, batch_s=10.0, clock=clock)
    heard.add("v/lidar", message(5, [1, 2]))
    assert reads == []  # waiting for others to join it
    got = heard.get("v/lidar")
    assert got is not None and (got.stamp_ns, got.next_id, got.epoch) == (5, 3, 3)
    heard.add("v/radar", message(6, [9]))
    heard.forget_payloads(lambda stream: stream != "v/radar")
    radar = heard.get("v/radar")
    assert radar is not None and radar.payload is None and radar.next_id == 10
    assert len(reads) == 2


def test_messages_are_read_together_when_the_batch_is_full_or_its_first_is_old(
    reads: list[bytes],
) -> None:
    clock = Clock()
    heard = HeardStreams(OWN, batch=4, batch_s=0.05, clock=clock)
    for k in range(3):
        heard.add(f"v/s{k}", message(k, [k]))
    assert reads == []
    heard.add("v/s3", message(3, [3]))
    assert len(reads) == 4  # full: all four, in the order they came
    assert [msgpack.unpackb(p)["stamp_ns"] for p in reads] == [0, 1, 2, 3]
    heard.add("v/s4", message(4, [4]))
    clock.t += 0.049
    heard.add("v/s5", message(5, [5]))
    assert len(reads) == 4
    clock.t += 0.002  # the first waiting one is 51 ms old
    heard.add("v/s6", message(6, [6]))
    assert len(reads) == 7


def test_a_stream_keeps_its_newest_message_and_the_highest_id_and_epoch_heard() -> None:
    heard = HeardStreams(OWN, batch=64, batch_s=10.0, clock=Clock())
    newest = message(20, [4], epoch=5)
    heard.add("v/s", newest)
    heard.add("v/s", message(10, [1, 30], epoch=4))  # an older frame, a higher id
    got = heard.get("v/s")
    assert got is not None
    assert (got.stamp_ns, got.next_id, got.epoch, got.payload) == (20, 31, 5, newest)


def test_its_own_messages_and_garbage_teach_nothing_and_cost_the_others_nothing(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    heard = HeardStreams(OWN, batch=4, batch_s=10.0, clock=Clock())
    peek = heard_module.peek_heard

    def breaks_on(payload: bytes) -> tuple[int, int, int | None] | None:
        if payload == b"boom":
            raise RuntimeError("a reader bug")
        return peek(payload)

    monkeypatch.setattr(heard_module, "peek_heard", breaks_on)
    heard.add("v/own", message(1, [1], instance="member-b"))
    heard.add("v/garbage", b"\xc1\xc1")
    heard.add("v/boom", b"boom")
    heard.add("v/good", message(2, [7]))
    assert [heard.get(s) for s in ("v/own", "v/garbage", "v/boom")] == [None] * 3
    good = heard.get("v/good")
    assert good is not None and good.next_id == 8


def test_a_fused_vehicle_s_messages_give_their_seq() -> None:
    heard = HeardStreams(OWN, batch=64, batch_s=10.0, clock=Clock())
    heard.add("truck-07/@vehicle", generate._vehicle_tracks(epoch=2), vehicle=True)
    got = heard.get("truck-07/@vehicle")
    assert got is not None and (got.seq, got.next_id, got.epoch) == (1042, 13, 2)


def test_messages_from_two_threads_are_all_read_once_while_others_look() -> None:
    heard = HeardStreams(OWN, batch=16, batch_s=0.001)
    n = 2000
    looked: list[int] = []

    def put(prefix: str) -> None:
        for k in range(n):
            heard.add(f"{prefix}/s{k % 50}", message(k, [k]))

    def look() -> None:
        for _ in range(200):
            got = heard.get("a/s0")
            looked.append(-1 if got is None else got.stamp_ns)

    threads = [threading.Thread(target=put, args=(p,)) for p in ("a", "b")]
    threads.append(threading.Thread(target=look))
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert len(heard) == 100
    for prefix in ("a", "b"):
        for s in range(50):
            got = heard.get(f"{prefix}/s{s}")
            last = n - 50 + s
            assert got is not None and (got.stamp_ns, got.next_id) == (last, last + 1)
    assert looked == sorted(looked)  # what one looks at never goes back


def test_it_holds_at_most_max_streams() -> None:
    heard = HeardStreams(OWN, batch=1, max_streams=3)
    for k in range(5):
        heard.add(f"v/s{k}", message(k, [k]))
    assert len(heard) == 3 and heard.get("v/s4") is None


@pytest.mark.parametrize(
    ("kwargs", "says"), [({"batch": 0}, "got 0"), ({"batch_s": float("nan")}, "got nan")]
)
def test_bad_settings_are_refused_with_the_value(kwargs: dict[str, Any], says: str) -> None:
    with pytest.raises(ValueError, match=says):
        HeardStreams(OWN, **kwargs)
