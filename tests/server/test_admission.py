"""Admission at max_sensors (no Zenoh): a sensor silent for over reclaim_after_s gives way to
a new one, the longest silent first; a sensor that keeps sending never does."""

from __future__ import annotations

import time

from simpletrack.core.config import preset
from simpletrack.core.tracker import Tracker
from simpletrack.server.metrics import Metrics
from simpletrack.server.registry import SensorRegistry
from simpletrack.server.sensors import SensorBudget


def registry(budget: SensorBudget, metrics: Metrics, reclaim_after_s: float) -> SensorRegistry:
    config = preset("kitti")
    return SensorRegistry(
        budget=budget,
        metrics=metrics,
        new_tracker=lambda: Tracker(config),
        digest="d",
        writer=None,
        state_dir=None,
        reclaim_after_s=reclaim_after_s,
    )


def reclaimed(m: Metrics) -> float | None:
    return m.registry.get_sample_value("simpletrack_sensors_reclaimed_total")


def evicted(m: Metrics) -> float | None:
    return m.registry.get_sample_value("simpletrack_sensors_evicted_total")


def silence(reg: SensorRegistry, name: str, seconds: float) -> None:
    state = reg.get(name)
    assert state is not None
    state.last_seen = time.monotonic() - seconds


def test_at_capacity_the_longest_silent_sensor_gives_way_to_a_new_one() -> None:
    m = Metrics()
    reg = registry(SensorBudget(3), m, reclaim_after_s=5.0)
    for i in range(3):
        assert reg.add("v", f"probe{i}", 0) is not None
    silence(reg, "v/probe0", 6.0)
    silence(reg, "v/probe1", 9.0)
    silence(reg, "v/probe2", 1.0)  # not silent long enough to go
    assert reg.add("v", "new", 0) is not None
    assert sorted(s for _, s in reg.names()) == ["new", "probe0", "probe2"]
    assert [s.sensor for s in reg.reclaimed_now] == ["probe1"]
    assert reclaimed(m) == 1 and evicted(m) == 0


def test_at_capacity_with_every_sensor_sending_a_new_one_is_refused() -> None:
    reg = registry(SensorBudget(2), Metrics(), reclaim_after_s=5.0)
    reg.add("v", "a", 0)
    reg.add("v", "b", 0)
    silence(reg, "v/a", 4.9)
    assert reg.add("v", "new", 0) is None
    assert len(reg) == 2


def test_a_reclaimed_sensor_coming_back_continues_above_its_ids() -> None:
    reg = registry(SensorBudget(1), Metrics(), reclaim_after_s=1.0)
    a = reg.add("v", "a", 0)
    assert a is not None
    a.tracker.next_id = 7  # as if it had published ids 0..6
    silence(reg, "v/a", 2.0)
    assert reg.add("v", "b", 0) is not None
    silence(reg, "v/b", 2.0)
    back = reg.add("v", "a", 0)
    assert back is not None and back.id_base == 7


def test_housekeeping_reclaims_early_only_while_every_slot_is_taken() -> None:
    budget = SensorBudget(3)
    m = Metrics()
    here, other = registry(budget, m, 1.0), registry(budget, m, 1.0)
    here.add("v", "a", 0)
    here.add("v", "b", 0)
    silence(here, "v/a", 2.0)
    assert here.evict_idle(time.monotonic(), idle_s=600.0) == []  # a slot is free: keep
    other.add("v", "c", 0)  # every slot taken: a quiet sensor on any worker gives way
    gone = here.evict_idle(time.monotonic(), idle_s=600.0)
    assert [s.sensor for s in gone] == ["a"] and budget.used == 2
    assert reclaimed(m) == 1
