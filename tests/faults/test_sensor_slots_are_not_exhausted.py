"""Item 7: one-frame sensors that fill max_sensors and go quiet give way to a new sensor
once silent for over reset_gap_s; a sensor that keeps sending keeps its slot and its ids."""

from __future__ import annotations

import time
from pathlib import Path

import pytest

from simpletrack.wire import ErrorReason
from tests.service_helpers import client, metric, moving_cars, stamp, start_service, wait_for

pytestmark = pytest.mark.zenoh

SLOTS, QUIET_S = 6, 1.0


def test_quiet_one_frame_sensors_give_way_and_a_live_one_keeps_its_slot(tmp_path: Path) -> None:
    env = {
        "SIMPLETRACK_WORKERS": "2",  # probes on both workers: the rule holds across workers
        "SIMPLETRACK_MAX_SENSORS": str(SLOTS),
        "SIMPLETRACK_RESET_GAP_S": str(QUIET_S),
    }
    svc = start_service(tmp_path, env=env, instance="svc-slots")
    try:
        with client(svc.endpoint) as cli:
            live_k = 0

            def live_frame() -> None:
                nonlocal live_k
                cli.send(
                    "veh", "live", seq=live_k, stamp_ns=stamp(live_k), boxes=moving_cars(live_k)
                )
                live_k += 1

            live_frame()
            for i in range(SLOTS - 1):  # one box, one frame each, then silence
                cli.send("probe", f"p{i}", seq=0, stamp_ns=stamp(0), boxes=moving_cars(0, n=1))
            wait_for(lambda: sum(map(len, cli.received.tracks.values())) == SLOTS, 10, "probes")

            # Every slot taken and nobody silent long enough: a new sensor is refused.
            cli.send("veh", "new", seq=0, stamp_ns=stamp(0), boxes=moving_cars(0))
            wait_for(lambda: cli.received.n_errors("veh/new") == 1, 10, "the refusal")
            assert cli.received.errors["veh/new"][0].reason is ErrorReason.TOO_MANY_SENSORS

            # The live sensor keeps sending at 10 Hz while the probes stay quiet.
            deadline = time.monotonic() + QUIET_S + 1.0  # past reset_gap_s and a housekeeping
            while time.monotonic() < deadline:
                live_frame()
                time.sleep(0.1)
            cli.send("veh", "new", seq=1, stamp_ns=stamp(1), boxes=moving_cars(1))
            wait_for(lambda: cli.received.n_tracks("veh/new") == 1, 10, "the new sensor admitted")
            assert cli.received.n_errors("veh/new") == 1  # only the refusal before
            live_frame()
            wait_for(lambda: cli.received.n_tracks("veh/live") == live_k, 10, "live frames")
            assert cli.received.n_errors("veh/live") == 0

            # The live sensor kept its tracker: the same ids all along, no reset.
            ids = [set(a.id.tolist()) for _, a in cli.received.tracks["veh/live"][2:]]
            assert all(i == ids[0] for i in ids) and len(ids[0]) == 3
            m = svc.metrics()
            # Quiet probes gave way while every slot was taken (a worker's whole batch at once),
            # never the live sensor, and none past sensor_idle_s.
            reclaimed = metric(m, "simpletrack_sensors_reclaimed_total")
            assert 1 <= reclaimed <= SLOTS - 1
            assert metric(m, "simpletrack_sensors_evicted_total") == 0
            assert metric(m, "simpletrack_active_sensors") == SLOTS - reclaimed + 1
            assert (
                sum(
                    metric(m, "simpletrack_tracker_resets_total", reason=r)
                    for r in ("gap", "time_backwards")
                )
                == 0
            )
    finally:
        assert svc.stop() == 0
