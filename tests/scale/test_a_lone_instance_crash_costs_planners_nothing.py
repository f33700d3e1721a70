"""A lone instance (the embedded default: no group to fail over to) SIGKILLed at the worst
moment, just before its next snapshot, and restarted on its state directory by a supervisor:
the restart replays the gap since its snapshot from the vehicles' advanced-publisher caches,
so every frame is answered and every answer equals an uninterrupted run's tracks, ids
included (the frames answered before the kill may come twice: at least once on the wire).
A vehicle that publishes with a plain put keeps no cache: its gap is announced as missed and
no id it published before is given to a new track."""

from __future__ import annotations

import signal
import threading
import time
from pathlib import Path

import zenoh

from simpletrack.session import open_session
from simpletrack.spawn import free_port
from simpletrack.wire import (
    BoxArrays,
    FrameError,
    Rejection,
    TrackArrays,
    TrackFrame,
    decode_message,
)
from simpletrack.wire.codec import encode_detection_frame
from tests.faults.router_process import start_client_service
from tests.faults.vehicle import start_router
from tests.scale.fleet import (
    Fleet,
    Planner,
    expected_tracks,
    fleet_frames,
    needs_kitti,
    same_tracks,
    stamp_of,
)
from tests.service_helpers import ServiceProcess, wait_for

CACHED = ("car-1/lidar", "car-3/lidar")
PLAIN = "car-4/lidar"  # a plain put: no cache to replay from
SNAPSHOT_S = 5.0  # the default snapshot_interval_s
N = 230


class PlainFleet(Fleet):
    """``Fleet`` whose sensor ``PLAIN`` publishes with a plain ``put`` (no advanced publisher)."""

    def __init__(self, session: zenoh.Session, frames: dict[str, list[BoxArrays]]) -> None:
        super().__init__(session, {k: v for k, v in frames.items() if k != PLAIN})
        self.plain = frames[PLAIN]
        self.session = session

    def run(self) -> None:
        t0 = time.monotonic()
        vehicle, sensor = PLAIN.split("/")
        for k in range(min(self.n, len(self.plain))):
            if self._halt.wait(max(0.0, t0 + k * 0.1 - time.monotonic())):
                break
            for name, pub in self.pubs.items():
                pub.publish_arrays(self.frames[name][k], stamp_ns=stamp_of(k))
            payload = encode_detection_frame(
                vehicle=vehicle, sensor=sensor, seq=k, stamp_ns=stamp_of(k), frame_id=sensor,
                boxes=self.plain[k],
            )  # fmt: skip
            self.session.put(f"fleet/{vehicle}/{sensor}/detections", payload)
            self.k = k
        self.done.set()


def _last_snapshot(state: Path) -> float:
    """When the newest snapshot file was written (0: none yet)."""
    times = [p.stat().st_mtime for p in state.rglob("*.snap")]
    return max(times, default=0.0)


@needs_kitti
def test_a_lone_instance_killed_before_its_snapshot_changes_no_track(tmp_path: Path) -> None:
    everything = fleet_frames(5, N)  # KITTI sequences 1, 3, 4 have N frames and more
    frames = {name: everything[name] for name in (*CACHED, PLAIN)}
    n = min(len(v) for v in frames.values())
    assert n == N, n
    port = free_port()
    router = f"tcp/127.0.0.1:{port}"
    router_proc = start_router(port)
    state = tmp_path / "state"
    args = ("--state-dir", str(state))
    env = {"SIMPLETRACK_QUEUE_SIZE": "1000"}
    errors: list[FrameError] = []
    lock = threading.Lock()

    def on_error(sample: zenoh.Sample) -> None:
        err = decode_message(sample.payload.to_bytes(), FrameError)
        if not isinstance(err, Rejection):
            with lock:
                errors.append(err)

    def serve() -> ServiceProcess:
        svc = start_client_service(tmp_path, router, *args, env=env, instance="lone")
        wait_for(lambda: svc.http("/readyz")[0] == 200, 60, "the service ready")
        return svc

    svc = serve()
    fleet: PlainFleet | None = None
    try:
        with open_session(mode="client", connect=[router]) as session:
            planner = Planner()
            subs = [
                session.declare_subscriber("fleet/*/*/tracks", planner.on_tracks),
                session.declare_subscriber("fleet/*/*/errors", on_error),
            ]
            fleet = PlainFleet(session, frames)
            assert fleet.wait_for_service(10)
            fleet.start()
            wait_for(lambda: fleet is not None and fleet.k >= 60, 30, "6 s of frames")
            # The worst moment: just before the next periodic snapshot.
            wait_for(lambda: _last_snapshot(state) > 0, 20, "a first snapshot")
            # Late in the interval (each worker writes its own sensors' snapshots, a few
            # hundred ms apart: the newest file is never a whole interval old).
            wait_for(
                lambda: time.time() - _last_snapshot(state) > SNAPSHOT_S - 1.5,
                2 * SNAPSHOT_S + 2,
                "a moment late before the next snapshot",
            )
            svc.stop(signal.SIGKILL)
            killed_ns = time.time_ns()
            svc = serve()  # a supervisor's restart, on the same state directory
            wait_for(lambda: fleet is not None and fleet.done.is_set(), 60, "the whole run")
            time.sleep(1.0)
            for s in subs:
                s.undeclare()
        logs = [x for x in svc.logs() if x.get("event") == "sensor_taken_over"]
        by = {f"{x['vehicle']}/{x['sensor']}": x for x in logs}
        with planner.lock:
            got: dict[str, list[tuple[TrackFrame, TrackArrays]]] = {
                k: list(v) for k, v in planner.frames.items()
            }
        for name in CACHED:
            taken = by[name]
            assert taken["source"] == "restore" and taken["missed"] == 0, taken
            assert taken["from_vehicle_cache"] > 0 and taken["exact_ids"], taken
            expected = expected_tracks(name, frames[name][:n])
            answers: dict[int, list[TrackArrays]] = {}
            for f, t in got[name]:
                answers.setdefault(f.seq, []).append(t)
            unanswered = [q for q in range(n) if q not in answers]
            assert not unanswered, f"{name}: {len(unanswered)} frames unanswered"
            unequal = [q for q in range(n) for a in answers[q] if not same_tracks(a, expected[q])]
            assert not unequal, f"{name}: seqs {unequal[:10]} differ from an uninterrupted run"
        with lock:
            missed = [e for e in errors if e.reason.value == "missed" and e.sensor == "lidar"]
        assert [f"{e.vehicle}/{e.sensor}" for e in missed] == [PLAIN], missed
        before = {int(i) for f, t in got[PLAIN] if f.received_ns < killed_ns for i in t.id}
        after = {int(i) for f, t in got[PLAIN] if f.received_ns > killed_ns for i in t.id}
        born = after - before
        assert born and min(born) > max(before), (sorted(before), sorted(after))
    finally:
        if fleet is not None:
            fleet.close()
        svc.stop()
        router_proc.kill()
