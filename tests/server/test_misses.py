"""Frames lost in transport (server/misses.py): each miss is counted and its notice goes
through the member's announcer, so a planner hears of the missed frames before the tracks of
the frames after them, and a notice the announcer cannot hold is counted and logged, never
lost silently. A fake session stands for Zenoh; Zenoh's miss and sample are duck-typed."""

from __future__ import annotations

import threading
from types import SimpleNamespace
from typing import Any

import pytest

from simpletrack.server.announcer import Announcer
from simpletrack.server.metrics import Metrics
from simpletrack.server.misses import MissCounter
from simpletrack.wire import FrameError, Rejection
from simpletrack.wire.codec import decode_message
from simpletrack.wire.keys import Keys
from simpletrack.wire.reasons import ErrorReason

KEYS = Keys("fleet")


class Session:
    """Records each put, in order."""

    def __init__(self) -> None:
        self.puts: list[tuple[str, bytes]] = []
        self.lock = threading.Lock()

    def put(self, key: str, payload: bytes, **_: Any) -> None:
        with self.lock:
            self.puts.append((key, payload))


def counter(announcer: Announcer, metrics: Metrics) -> tuple[MissCounter, list[Any]]:
    handed: list[Any] = []
    return MissCounter(handed.append, KEYS, metrics, "member-a", announcer), handed


def sample(vehicle: str, sensor: str, zid: str = "z1", eid: int = 7) -> Any:
    source = SimpleNamespace(source_id=SimpleNamespace(zid=zid, eid=eid))
    return SimpleNamespace(key_expr=KEYS.detections(vehicle, sensor), source_info=source)


def miss(nb: int, zid: str = "z1", eid: int = 7) -> Any:
    return SimpleNamespace(source=SimpleNamespace(zid=zid, eid=eid), nb=nb)


def missed(metrics: Metrics) -> float:
    value = metrics.registry.get_sample_value(
        "simpletrack_frames_dropped_total", {"reason": ErrorReason.MISSED.value}
    )
    return value or 0.0


def test_a_miss_is_announced_before_the_tracks_of_the_frames_after_it() -> None:
    session, metrics = Session(), Metrics()
    announcer = Announcer(session, None, metrics)  # type: ignore[arg-type]
    misses, handed = counter(announcer, metrics)
    misses(sample("car", "lidar"))  # the publisher's first frame: its key learnt
    # Zenoh reports the gap, then hands on the frame after it; its worker answers it while
    # the announcer has not yet published (its thread not started here).
    misses.on_miss(miss(25))
    misses(sample("car", "lidar"))
    assert len(handed) == 2
    assert announcer.behind(KEYS.tracks("car", "lidar"), b"tracks", ("car", "lidar"))
    announcer.start()
    announcer.close(5.0)
    assert [key for key, _ in session.puts] == [
        KEYS.errors("car", "lidar"),
        KEYS.tracks("car", "lidar"),
    ]
    err = decode_message(session.puts[0][1], FrameError)
    assert not isinstance(err, Rejection), err
    assert err.reason is ErrorReason.MISSED and err.detail.startswith("25 frames")
    assert (err.vehicle, err.sensor, err.instance) == ("car", "lidar", "member-a")
    assert missed(metrics) == 25 and misses.missed("car", "lidar") == 25


def test_a_miss_past_the_announcers_backlog_is_counted_and_logged_not_lost() -> None:
    session, metrics = Session(), Metrics()
    announcer = Announcer(session, None, metrics, limit_bytes=1)  # type: ignore[arg-type]
    misses, _ = counter(announcer, metrics)
    misses.announce("car", "lidar", 3, "lost in transport")
    assert missed(metrics) == 3
    assert metrics.registry.get_sample_value("simpletrack_error_notices_dropped_total") == 1
    assert session.puts == []


@pytest.mark.parametrize("known", [True, False])
def test_a_miss_is_charged_to_the_sensor_of_its_publisher(known: bool) -> None:
    session, metrics = Session(), Metrics()
    announcer = Announcer(session, None, metrics)  # type: ignore[arg-type]
    misses, _ = counter(announcer, metrics)
    misses(sample("car", "lidar", eid=7))
    misses(sample("car", "camera", eid=8))
    misses.on_miss(miss(4, eid=8 if known else 9))
    announcer.start()
    announcer.close(5.0)
    # A publisher not heard yet has no sensor: counted, logged, nothing to announce it on.
    assert missed(metrics) == 4
    assert misses.missed("car", "camera") == (4 if known else 0)
    assert [key for key, _ in session.puts] == ([KEYS.errors("car", "camera")] if known else [])
