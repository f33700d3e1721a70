"""Fused vehicles are streams like sensors (server/streams.py): three members share six
vehicles, each a lidar at 10 Hz and a camera at 15 Hz fused into one track list; the member
owning a vehicle is killed with SIGKILL mid-stream. Every vehicle message (by the vehicle's
seq) reaches the planner exactly once (on the wire the killed member's last one may come
twice, from two members), and its tracks are those the core's fused tracker gives on the
same frames in stamp order, message for message: the vehicle's stream was taken over with
its checkpoint and the frames since, replayed through its reorder window."""

from __future__ import annotations

import contextlib
import signal
import threading
import time
from pathlib import Path

import numpy as np
import pytest
import zenoh

from simpletrack.client import DetectionPublisher, VehicleTrackMessage, VehicleTrackSubscriber
from simpletrack.server.group import ranking
from simpletrack.wire import Rejection, decode_vehicle_track_frame
from tests.fusion_scenario import CLASSES, WireFrame, expected, frames, fusion_of, write_config
from tests.scale.fleet import Group, planner_session
from tests.service_helpers import wait_for

pytestmark = pytest.mark.zenoh
VEHICLES = 6
SECONDS = 8.0


class FusedFleet(threading.Thread):
    """Each vehicle's lidar and camera frames, published in stamp order at their stamps'
    pace (advanced publishers with their caches, each with its extrinsic)."""

    def __init__(self, session: zenoh.Session, wire: list[WireFrame]) -> None:
        super().__init__(daemon=True)
        self.wire = wire
        self.pubs = {
            (f"veh{v:02d}", sensor): DetectionPublisher(
                session, f"veh{v:02d}", sensor, classes=CLASSES, extrinsic=extrinsic
            )
            for v in range(VEHICLES)
            for sensor, extrinsic in {f.sensor: f.extrinsic for f in wire}.items()
        }
        self.t = -1.0  # stamp seconds sent so far
        self._halt = threading.Event()

    def run(self) -> None:
        t0, s0 = time.monotonic(), self.wire[0].stamp_ns
        for f in self.wire:
            at = (f.stamp_ns - s0) * 1e-9
            if self._halt.wait(max(0.0, t0 + at - time.monotonic())):
                return
            for v in range(VEHICLES):
                pub = self.pubs[(f"veh{v:02d}", f.sensor)]
                pub.publish_arrays(f.boxes, stamp_ns=f.stamp_ns, seq=f.seq)
            self.t = at

    def close(self) -> None:
        self._halt.set()
        self.join(10)
        for p in self.pubs.values():
            with contextlib.suppress(Exception):
                p.close()


def test_a_killed_owner_of_fused_vehicles_changes_no_fused_track(tmp_path: Path) -> None:
    config = write_config(tmp_path)
    wire = frames(SECONDS, time.time_ns() - 60_000_000_000)
    want = expected(wire, fusion_of(config))
    group = Group(tmp_path, args=("--config", str(config)))
    fleet = None
    try:
        for name in ("m-a", "m-b", "m-c"):
            group.add(name)
        with planner_session(group) as session:
            raw: dict[str, list[tuple[int, str]]] = {}
            lock = threading.Lock()

            def on_raw(sample: zenoh.Sample) -> None:
                out = decode_vehicle_track_frame(sample.payload.to_bytes())
                assert not isinstance(out, Rejection), out
                with lock:
                    raw.setdefault(out[0].vehicle, []).append((out[0].seq, out[0].instance))

            sub = session.declare_subscriber("fleet/*/@vehicle/tracks", on_raw)
            delivered: dict[str, list[VehicleTrackMessage]] = {}

            def deliver(m: VehicleTrackMessage) -> None:
                with lock:
                    delivered.setdefault(m.vehicle, []).append(m)

            fused = VehicleTrackSubscriber(session, callback=deliver)
            fleet = FusedFleet(session, wire)
            assert all(p.wait_for_service(10) for p in fleet.pubs.values())
            fleet.start()
            wait_for(lambda: fleet.t >= 3.0, 20, "3 s of frames")
            victim = ranking(group.members, "veh00/@vehicle")[0]
            group.remove(victim).stop(signal.SIGKILL)
            fleet.join(SECONDS + 20)
            wait_for(
                lambda: all(len(delivered.get(f"veh{v:02d}", [])) >= len(want)
                            for v in range(VEHICLES)),
                20,
                "every vehicle's messages",
            )  # fmt: skip
            time.sleep(0.5)
            sub.undeclare()
            fused.close()
    finally:
        if fleet is not None:
            fleet.close()
        group.stop_all()
    moved = [f"veh{v:02d}" for v in range(VEHICLES)
             if ranking({victim, *group.members}, f"veh{v:02d}/@vehicle")[0] == victim]  # fmt: skip
    assert "veh00" in moved
    for v in range(VEHICLES):
        vehicle = f"veh{v:02d}"
        got = delivered[vehicle]
        assert [m.seq for m in got] == list(range(len(want))), vehicle
        for m, w in zip(got, want, strict=True):
            np.testing.assert_array_equal(m.tracks.id, w.id, err_msg=f"{vehicle} seq {m.seq}")
            np.testing.assert_array_equal(m.tracks.center, w.center, err_msg=vehicle)
        seqs = [s for s, _ in raw[vehicle]]
        repeats = len(seqs) - len(set(seqs))
        assert repeats <= (1 if vehicle in moved else 0), (vehicle, repeats)
        instances = {i for _, i in raw[vehicle]}
        assert (victim in instances) and (len(instances) == 2) if vehicle in moved else True
