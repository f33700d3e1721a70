"""The announcer (server/announcer.py): the workers' refusal notices published from its own
thread, in order, with a sensor's tracks kept behind its waiting notices; a put held by a
slow subscriber never holds the caller; past the backlog a notice is counted and logged,
never lost silently. A fake session stands for Zenoh."""

from __future__ import annotations

import threading
import time
from collections.abc import Iterator
from typing import Any

import pytest

from simpletrack.server.announcer import ITEM_OVERHEAD, Announcer
from simpletrack.server.metrics import Metrics
from tests.server.fake_clock import Clock
from tests.service_helpers import LogEvents, log_events

CAR = ("car", "lidar")
BUS = ("bus", "lidar")


class Session:
    """Records each put; ``hold`` makes puts wait (a subscriber that does not read)."""

    def __init__(self) -> None:
        self.puts: list[tuple[str, bytes]] = []
        self.hold = threading.Event()
        self.hold.set()
        self.entered = threading.Event()

    def put(self, key: str, payload: bytes, **_: Any) -> None:
        self.entered.set()
        self.hold.wait()
        self.puts.append((key, payload))


@pytest.fixture
def events() -> Iterator[LogEvents]:
    with log_events("simpletrack.pool") as handler:
        yield handler


def announcer(session: Session, **kw: Any) -> tuple[Announcer, Metrics]:
    metrics = Metrics()
    a = Announcer(session, None, metrics, **kw)  # type: ignore[arg-type]
    a.start()
    return a, metrics


def dropped(metrics: Metrics) -> float:
    return metrics.registry.get_sample_value("simpletrack_error_notices_dropped_total") or 0.0


def wait_until(pred: Any, timeout: float = 5.0) -> None:
    deadline = time.monotonic() + timeout
    while not pred():
        assert time.monotonic() < deadline, "timed out"
        time.sleep(0.001)


def test_notices_are_published_in_order_and_tracks_wait_behind_their_sensors() -> None:
    session = Session()
    a, _ = announcer(session)
    session.hold.clear()
    assert a.announce("car/errors", b"e0", CAR)
    session.entered.wait(5)  # e0 is being published, held
    assert a.announce("car/errors", b"e1", CAR)
    # The car has notices waiting: its tracks go behind them; the bus has none: its worker
    # publishes its tracks itself, at once.
    assert a.behind("car/tracks", b"t2", CAR)
    assert not a.behind("bus/tracks", b"t0", BUS)
    assert a.pending(CAR) == 3 and a.pending(BUS) == 0
    session.hold.set()
    wait_until(lambda: len(session.puts) == 3)
    assert [p for _, p in session.puts] == [b"e0", b"e1", b"t2"]
    wait_until(lambda: a.pending(CAR) == 0)
    assert not a.behind("car/tracks", b"t3", CAR)  # nothing waits any more
    a.close(5)


def test_a_held_put_never_holds_the_caller_and_a_full_backlog_is_counted_and_logged(
    events: LogEvents,
) -> None:
    session, clock = Session(), Clock()
    a, metrics = announcer(session, limit_bytes=10 * (2 + ITEM_OVERHEAD), clock=clock)
    session.hold.clear()  # the subscriber stops reading
    t0 = time.perf_counter()
    took = [a.announce("car/errors", b"%02d" % k, CAR) for k in range(25)]
    assert time.perf_counter() - t0 < 0.5  # nothing waited for the held put
    # One is being published, 10 wait: the 14 after them are dropped, counted, and logged:
    # the first at once, the rest held back until the interval has passed.
    session.entered.wait(5)
    assert took.count(False) == dropped(metrics) >= 14
    lines = events.named("error_notices_dropped")
    assert [line["dropped"] for line in lines] == [1]
    assert (lines[0]["vehicle"], lines[0]["sensor"]) == CAR
    # The tracks of a sensor whose notices wait are never dropped: past the bound they go
    # back to the worker, which publishes them itself.
    assert not a.behind("car/tracks", b"t", CAR)
    clock.t += 10.0
    a.flush_logs()
    assert [line["dropped"] for line in events.named("error_notices_dropped")] == [
        1,
        dropped(metrics) - 1,
    ]
    session.hold.set()
    a.close(5)
    published = [p for _, p in session.puts]
    assert published == sorted(published) and len(published) + dropped(metrics) == 25


def test_what_still_waits_at_the_stop_past_the_deadline_is_counted_and_logged(
    events: LogEvents,
) -> None:
    session = Session()
    a, metrics = announcer(session)
    session.hold.clear()
    for k in range(5):
        assert a.announce("car/errors", b"%d" % k, CAR)
    session.entered.wait(5)
    a.close(0.1)  # the first is held in its put; the 4 behind it never go
    assert dropped(metrics) == 4
    assert events.named("error_notices_dropped")[-1]["at"] == "stop"
    assert not a.announce("car/errors", b"late", CAR)  # after the stop: counted too
    assert dropped(metrics) == 5
    session.hold.set()
