"""Refusal log lines under a flood (server/outbox.py RepeatLog): the first of each sensor and
reason, then the latest once per interval with how many were not logged; none lost from the
count, none held forever."""

from __future__ import annotations

from simpletrack.server.outbox import RepeatLog
from tests.server.fake_clock import Clock


def line(seq: int) -> dict[str, object]:
    return {"seq": seq}


def test_the_first_refusal_is_logged_then_one_line_per_interval_with_the_count() -> None:
    clock = Clock()
    log = RepeatLog(interval_s=10.0, clock=clock)
    car = ("car", "lidar")
    assert log.admit(car, "malformed", line(0)) == 0
    assert [log.admit(car, "malformed", line(k)) for k in range(1, 6)] == [None] * 5
    assert log.due() == []  # the interval has not passed
    clock.t += 10.0
    assert log.admit(car, "malformed", line(6)) == 5  # this line stands for 5 not logged
    assert log.admit(car, "malformed", line(7)) is None


def test_each_sensor_and_reason_has_its_own_first_line() -> None:
    log = RepeatLog(interval_s=10.0, clock=Clock())
    assert log.admit(("car", "lidar"), "malformed", line(0)) == 0
    assert log.admit(("car", "lidar"), "out_of_order", line(1)) == 0
    assert log.admit(("bus", "lidar"), "malformed", line(2)) == 0
    assert log.admit(("car", "lidar"), "malformed", line(3)) is None


def test_a_flood_that_stops_gets_its_latest_line_and_count_once_the_interval_passes() -> None:
    clock = Clock()
    log = RepeatLog(interval_s=10.0, clock=clock)
    car = ("car", "lidar")
    log.admit(car, "malformed", line(0))
    for k in range(1, 4):
        log.admit(car, "malformed", line(k))
    clock.t += 10.0
    assert log.due() == [(line(3), 2)]  # seq 3 logged, standing for 2 others (1 and 2)
    assert log.due() == []
    clock.t += 10.0
    assert log.admit(car, "malformed", line(4)) == 0  # nothing held back since


def test_forgotten_sensors_and_the_cap_bound_the_memory() -> None:
    log = RepeatLog(interval_s=10.0, cap=2, clock=Clock())
    log.admit(("a", "s"), "malformed", line(0))
    log.admit(("b", "s"), "malformed", line(0))
    log.forget(("a", "s"))
    assert log.admit(("a", "s"), "malformed", line(1)) == 0  # its first line again
    assert log.admit(("c", "s"), "malformed", line(0)) == 0  # past the cap: all forgotten
    assert log.admit(("b", "s"), "malformed", line(1)) == 0
