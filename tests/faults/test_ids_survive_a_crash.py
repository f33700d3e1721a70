"""A service killed with SIGKILL while a vehicle streams in real time, then restarted from its
state directory: the tracks alive at the crash keep their ids, and the frames sent while it
was down are answered: the restart replays them from the vehicle's cache (not a gap to
bridge, nor a jump of the sensor's clock)."""

from __future__ import annotations

import signal
import time
from pathlib import Path

from simpletrack.client import DetectionPublisher
from simpletrack.spawn import free_port
from tests.faults.vehicle import RealTimeVehicle, ids_since, last_ids, vehicle_options
from tests.service_helpers import client, metric, start_service, wait_for

SENSOR = "car-40/lidar"


def test_ids_of_live_tracks_survive_a_sigkill_and_restart(tmp_path: Path) -> None:
    port = free_port()
    args = ("--state-dir", str(tmp_path / "state"))
    env = {"SIMPLETRACK_SNAPSHOT_INTERVAL_S": "1"}
    svc = start_service(tmp_path, *args, env=env, port=port, instance="svc-crash")
    restarted = None
    try:
        with client(svc.endpoint) as cli:
            pub = DetectionPublisher.connect(
                "car-40", "lidar", classes=("Car",), options=vehicle_options(svc.endpoint)
            )
            assert pub.wait_for_service(10)
            vehicle = RealTimeVehicle(pub)
            vehicle.start()
            wait_for(lambda: cli.received.n_tracks(SENSOR) >= 30, 30, "3 s of tracks")
            time.sleep(1.5)  # at least one snapshot of the live tracks
            ids = last_ids(cli.received, SENSOR)
            assert len(ids) == 3
            svc.stop(signal.SIGKILL)
            killed_ns = time.time_ns()
            time.sleep(5.0)  # down longer than reset_gap_s (5 s): the case that renumbered
            restarted = start_service(tmp_path, *args, env=env, port=port, instance="svc-crash")
            wait_for(
                lambda: len(ids_since(cli.received, SENSOR, killed_ns)) >= 10,
                60,
                "10 frames after the restart",
            )
            vehicle.stop()
            after = ids_since(cli.received, SENSOR, killed_ns)
            assert after[0] == ids and after[-1] == ids, after
            m = restarted.metrics()
            assert metric(m, "simpletrack_tracker_resets_total", reason="gap") == 0
            assert metric(m, "simpletrack_sensors_restored_total") >= 1
        taken = [x for x in restarted.logs() if x.get("event") == "sensor_taken_over"]
        assert taken and taken[0]["source"] == "restore", taken
        assert taken[0]["from_vehicle_cache"] >= 40 and taken[0]["missed"] == 0, taken
        assert taken[0]["exact_ids"] is True, taken
        with cli.received.lock:
            seqs = sorted({f.seq for f, _ in cli.received.tracks[SENSOR]})
        assert seqs == list(range(seqs[0], seqs[-1] + 1)), "a frame of the outage unanswered"
    finally:
        for s in (svc, restarted):
            if s is not None:
                s.stop()
