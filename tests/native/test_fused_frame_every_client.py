"""A vehicle's fused tracks (VehicleTrackFrame) as the service makes them, read by every client:
Python, Rust and C++ decode the same values, and walk them to the same global ids,
existence, contributors and sensor states, for version 1 frames and version 2 (with a custody
epoch); and the Rust ``VehicleTrackSubscriber`` receives them over a real Zenoh session on
127.0.0.1 exactly as the Python ``VehicleTrackSubscriber`` does, dropping the same exact
repeats and fenced holders' messages.

The frames come from the service's own path, in process: the fused vehicle of
tests/fusion_scenario.py (a lidar and a front camera, cars crossing) through the vehicle
tracker (``VehicleTracker.apply``) and ``encode_vehicle_track_frame`` with the arguments the
service's ``FusedFrames._apply`` gives it (service/simpletrack/server/fused.py). Version 1:
the vehicle frame, no poses; version 2: the world frame (each detection frame carries its
pose, which the message echoes), an epoch, and the camera going silent halfway.

The JSON all three compare: the golden vectors' ``decoded`` form of the frame
(schemas/vectors) and a ``walk``: what a planner reads through each client's accessors.
"""

from __future__ import annotations

import json
import struct
import subprocess
from pathlib import Path
from typing import Any

import pytest
import zenoh

from simpletrack.client import VehicleTrackMessage, VehicleTrackSubscriber
from simpletrack.core.fusion_config import FusionConfig
from simpletrack.core.vehicle import SensorInput, VehicleTracker
from simpletrack.server.settings import load_settings
from simpletrack.session import open_session
from simpletrack.spawn import free_port
from simpletrack.wire import Rejection, decode_vehicle_track_frame
from simpletrack.wire.convert import boxes_from_wire, vehicle_tracks_to_wire
from simpletrack.wire.generate import decoded_json
from simpletrack.wire.keys import Keys
from simpletrack.wire.vehicle_tracks import encode_vehicle_track_frame
from tests.core.fusion_helpers import T0_NS, mount
from tests.fusion_scenario import VEHICLE, frames
from tests.native.cargo_build import BUILD_TIMEOUT_S, example
from tests.native.test_cpp_codec import build  # noqa: F401  (the C++ build, a fixture)
from tests.service_helpers import wait_for

pytestmark = pytest.mark.native

SECONDS = 2.0
SILENT_AFTER_S = 0.5
EPOCH = 3 << 16 | 0x2A  # what a service makes: takeovers << 16 | a tag of its name
# The vehicle's place in the world (vehicle -> world) for the version-2 run.
WORLD = mount(120.0, -40.0, 0.3)
WORLD[2, 3] = 1.25


def _fusion() -> FusionConfig:
    # tests/fusion_scenario.py's configuration, a sensor silent after 0.5 s.
    return FusionConfig.model_validate(
        {
            "window_s": 0.3,
            "history_s": 1.0,
            "silent_after_s": SILENT_AFTER_S,
            "sensors": {
                "lidar": {"max_range_m": 50.0},
                "camera": {"fov_deg": 90.0, "max_range_m": 70.0, "verify": False},
            },
        }
    )


def _service_messages(world: bool) -> list[dict[str, Any]]:
    """encode_vehicle_track_frame's arguments (but the epoch) for every message the service
    publishes on the scenario's frames, in order: what FusedFrames._apply passes it."""
    tracker_config = load_settings(None, {}).tracker_config()
    classes = tracker_config.class_names
    v = VehicleTracker(tracker_config, _fusion())
    out: list[dict[str, Any]] = []
    last_camera_ns = T0_NS
    for f in frames(SECONDS, T0_NS):
        t = (f.stamp_ns - T0_NS) * 1e-9
        if world and f.sensor == "camera" and t > SECONDS / 2:
            continue  # the camera goes quiet halfway
        if f.sensor == "camera":
            last_camera_ns = f.stamp_ns
        # The service's clock says whether a sensor is silent (its reorder buffer's view).
        v.set_silent("camera", f.stamp_ns - last_camera_ns > SILENT_AFTER_S * 1e9)
        # With poses (sensor -> world) the service tracks in the world frame, else it puts
        # the boxes in the vehicle's frame with the sensor's extrinsic (fused.py: transform).
        pose = WORLD @ f.extrinsic if world else None
        transform = f.extrinsic if pose is None else pose
        result = v.apply(
            SensorInput(f.sensor, f.seq, f.stamp_ns, boxes_from_wire(f.boxes), transform)
        )
        if result.tracks is None:
            continue
        vt = result.tracks
        out.append(
            {
                "vehicle": VEHICLE,
                "seq": vt.seq,
                "stamp_ns": vt.stamp_ns,
                "sensor": f.sensor,
                "sensor_seq": f.seq,
                "frame_id": "world" if world else "base_link",
                "pose": None if pose is None else pose.reshape(-1).tolist(),
                "instance": "svc-fused",
                "received_ns": f.stamp_ns + 2_000_000,
                "published_ns": f.stamp_ns + 3_500_000,
                "sensors": list(v.sensors),
                "sensor_state": [v.records[s].condition.value for s in v.sensors],
                "tracks": vehicle_tracks_to_wire(
                    vt.tracks, vt.existence, vt.sensor_stamp_ns, classes
                ),
            }
        )
    return out


@pytest.fixture(scope="module")
def payloads() -> list[bytes]:
    """Every message of both runs: version 1 (vehicle frame) and version 2 (world, epoch)."""
    v1 = [encode_vehicle_track_frame(**m) for m in _service_messages(world=False)]
    v2 = [encode_vehicle_track_frame(**m, epoch=EPOCH) for m in _service_messages(world=True)]
    return v1 + v2


def _walk(m: VehicleTrackMessage) -> dict[str, Any]:
    """What a planner reads through the Python VehicleTrackMessage's accessors."""
    return {
        "global_ids": m.global_ids,
        "existence": m.existence.tolist(),
        "contributors": [m.contributors(i) for i in range(len(m.tracks))],
        "sensor_state": {s: c.value for s, c in m.sensor_state.items()},
        "source": list(m.source),
        "epoch": m.epoch,
    }


def _python(payload: bytes) -> dict[str, Any]:
    decoded = decode_vehicle_track_frame(payload)
    assert not isinstance(decoded, Rejection), decoded
    msg = VehicleTrackMessage("", decoded[0], decoded[1], 0)
    return {"decoded": decoded_json("VehicleTrackFrame", payload)["decoded"], "walk": _walk(msg)}


def test_the_scenario_makes_both_versions_with_tracks_and_every_sensor_state(
    payloads: list[bytes],
) -> None:
    """The frames compared below hold what there is to get wrong."""
    values = [_python(p) for p in payloads]
    versions = [v["decoded"]["schema_version"] for v in values]
    assert 1 in versions and 2 in versions
    assert sum(v["decoded"]["tracks"]["count"] for v in values) > 100
    assert any(v["decoded"]["pose"] is not None for v in values)
    states = {s for v in values for s in v["walk"]["sensor_state"].values()}
    assert {"ok", "silent"} <= states, states
    contributors = [c for v in values for c in v["walk"]["contributors"]]
    assert any(len(c) == 2 for c in contributors) and any(len(c) == 1 for c in contributors)
    assert all(0.0 <= e <= 1.0 for v in values for e in v["walk"]["existence"])
    assert {v["walk"]["epoch"] for v in values} == {None, EPOCH}


@pytest.mark.timeout(BUILD_TIMEOUT_S + 100)
def test_python_rust_and_cpp_read_the_same_fused_frames(
    payloads: list[bytes],
    build: Path,  # noqa: F811
) -> None:
    python = [_python(p) for p in payloads]

    rust_run = subprocess.run(
        [str(example("decode_fused"))],
        input="".join(p.hex() + "\n" for p in payloads),
        capture_output=True,
        text=True,
        timeout=60,
        check=False,
    )
    assert rust_run.returncode == 0, rust_run.stderr
    rust = [json.loads(line) for line in rust_run.stdout.splitlines()]

    records = b"".join(b"j" + struct.pack("<I", len(p)) + p for p in payloads)
    cpp_run = subprocess.run(
        [str(build / "wire_decode")], input=records, capture_output=True, timeout=60, check=False
    )
    assert cpp_run.returncode == 0, cpp_run.stderr.decode()
    cpp = []
    for line in cpp_run.stdout.decode().splitlines():
        verdict, _, rest = line.partition("\t")
        assert verdict == "ok", line
        cpp.append(json.loads(rest))

    assert len(rust) == len(cpp) == len(python) == len(payloads)
    for k, (p, r, c) in enumerate(zip(python, rust, cpp, strict=True)):
        # Exact: each language writes a float32 as the float64 it widens to, shortest form.
        assert r == p, f"message {k}: rust differs from python"
        assert c == p, f"message {k}: c++ differs from python"


# --- a real Zenoh session -----------------------------------------------------------------


def _session(endpoint: str) -> zenoh.Session:
    """A peer listening on ``endpoint`` only, scouting off."""
    return open_session(mode="peer", listen=[endpoint], connect=[], multicast_scouting=False)


@pytest.mark.zenoh
@pytest.mark.timeout(BUILD_TIMEOUT_S + 100)
def test_the_rust_vehicle_subscriber_drops_a_repeat_and_a_fenced_holder_as_python_does() -> None:
    messages = _service_messages(world=True)[:6]
    assert len(messages) == 6

    def sent(k: int, epoch: int) -> bytes:
        return encode_vehicle_track_frame(**messages[k], epoch=epoch)

    # The holder at EPOCH publishes; a message comes again (a takeover's repeat); a fenced
    # holder's message (a lower epoch) and a payload that is no frame arrive between; then a
    # new holder (EPOCH + 1) sends again the last message it heard and goes on, while the
    # old holder, still publishing, is fenced.
    stream = [
        sent(0, EPOCH),
        sent(1, EPOCH),
        sent(1, EPOCH),  # repeat
        sent(2, EPOCH - 1),  # stale
        b"\xc1",  # invalid: malformed
        sent(2, EPOCH),
        sent(3, EPOCH),
        sent(3, EPOCH + 1),  # the new holder's repeat
        sent(4, EPOCH + 1),
        sent(5, EPOCH),  # stale: the old holder
        sent(5, EPOCH + 1),  # the last: every sample before it was judged when it arrives
    ]
    delivered = [sent(0, EPOCH), sent(1, EPOCH), sent(2, EPOCH), sent(3, EPOCH)]
    delivered += [sent(4, EPOCH + 1), sent(5, EPOCH + 1)]

    endpoint = f"tcp/127.0.0.1:{free_port()}"
    key = Keys().vehicle_tracks(VEHICLE)
    with _session(endpoint) as session:
        publisher = session.declare_publisher(key, congestion_control=zenoh.CongestionControl.BLOCK)
        # fmt: off
        cmd = [str(example("subscribe")), "--endpoint", endpoint, "--vehicle", VEHICLE,
               "--fused", "--count", str(len(delivered)), "--idle-s", "15"]
        # fmt: on
        proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        try:
            wait_for(
                lambda: publisher.matching_status.matching or proc.poll() is not None,
                30,
                "the rust subscriber",
            )
            assert proc.poll() is None, proc.communicate()
            # Declared once the Rust one matched (matching counts local subscribers too).
            python_sub = VehicleTrackSubscriber(session, vehicle=VEHICLE)
            for payload in stream:
                publisher.put(payload)
            stdout, stderr = proc.communicate(timeout=60)
        finally:
            if proc.poll() is None:
                proc.kill()
                proc.communicate()
        wait_for(lambda: python_sub.received >= len(delivered), 10, "the python subscriber")
        python_got = [python_sub.try_recv() for _ in range(python_sub.received)]
        python_counts = (python_sub.duplicates, python_sub.stale, python_sub.invalid)
        python_sub.close()

    assert proc.returncode == 0, stderr
    rust_lines = [json.loads(line) for line in stdout.splitlines()]
    assert all("key" in line for line in rust_lines), rust_lines  # no error notices
    summary = json.loads(stderr.strip().splitlines()[-1])["summary"]
    assert summary["messages"] == summary["received"] == len(delivered), summary
    assert (summary["duplicates"], summary["stale"], summary["invalid"]) == (2, 2, 1), summary
    assert summary["invalid_reasons"] == {"malformed": 1}, summary
    assert summary["dropped"] == 0, summary
    assert python_counts == (2, 2, 1)

    assert all(line["key"] == key for line in rust_lines)
    rust = [{"decoded": line["decoded"], "walk": line["walk"]} for line in rust_lines]
    want = [_python(p) for p in delivered]
    assert [m["decoded"]["seq"] for m in rust] == [m["decoded"]["seq"] for m in want]
    assert rust == want
    # The Python subscriber on the publishing session delivered the same messages.
    assert len(python_got) == len(delivered)
    for m, payload, w in zip(python_got, delivered, want, strict=True):
        assert m is not None
        decoded = decode_vehicle_track_frame(payload)
        assert not isinstance(decoded, Rejection)
        assert m.frame == decoded[0]
        assert _walk(m) == w["walk"]
