"""The Rust vehicle client (clients/rust): its own tests (every golden vector both ways), a
Rust vehicle tracked by a real service (in both subscription modes) exactly as the Python
core tracks the same boxes, and its encoding of the cross-language fixture frame."""

from __future__ import annotations

import json
import subprocess
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from simpletrack.core.config import preset
from simpletrack.core.tracker import Tracker
from simpletrack.wire import BoxArrays, FrameError, Rejection
from simpletrack.wire.codec import (
    decode_detection_frame,
    decode_message,
    decode_track_frame,
    encode_detection_frame,
)
from simpletrack.wire.convert import frame_from_wire, tracks_to_wire
from simpletrack.wire.vehicle_tracks import decode_vehicle_track_frame
from tests.native.cargo_build import BUILD_TIMEOUT_S, cargo, example
from tests.native.fixture_frame import assert_same_frame, reference_payload
from tests.native.payload_cases import cases
from tests.service_helpers import start_service

pytestmark = pytest.mark.native

FRAMES = 20
# Each of these may be the first to build the crate: a cold build takes minutes.
BUILDS = pytest.mark.timeout(BUILD_TIMEOUT_S + 100)


@BUILDS
def test_cargo_test_passes_every_golden_vector_both_ways() -> None:
    out = cargo("test")
    assert out.returncode == 0, f"cargo test failed:\n{out.stdout[-4000:]}\n{out.stderr[-4000:]}"
    for name in (
        "valid_vectors_decode_to_their_json_and_reencode_byte_exact",
        "invalid_vectors_are_refused_with_their_reason_and_field",
    ):
        assert f"{name} ... ok" in out.stdout, f"{name} did not run:\n{out.stdout[-4000:]}"


def _run_publisher(
    endpoint: str, vehicle: str, *extra: str, frames: int = FRAMES
) -> list[dict[str, Any]]:
    publish = example("publish")
    # fmt: off
    cmd = [str(publish), "--endpoint", endpoint, "--vehicle", vehicle, "--sensor", "lidar",
           "--frames", str(frames), "--timeout-s", "20", *extra]
    # fmt: on
    out = subprocess.run(cmd, capture_output=True, text=True, timeout=120, check=False)
    assert out.returncode == 0, f"publish exited {out.returncode}:\n{out.stdout}\n{out.stderr}"
    return [json.loads(line) for line in out.stdout.splitlines()]


def _arrays(d: dict[str, Any]) -> BoxArrays:
    return BoxArrays(
        classes=tuple(d["classes"]),
        class_index=np.array(d["class_index"], np.int32),
        center=np.array(d["center"], np.float32).reshape(-1, 3),
        size=np.array(d["size"], np.float32).reshape(-1, 3),
        yaw=np.array(d["yaw"], np.float32),
        score=np.array(d["score"], np.float64),
        velocity=None if d["velocity"] is None else np.array(d["velocity"], np.float32),
    )


def _python_tracks(lines: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """What the Python core gives on the same boxes, the way the service feeds it: the
    detections through the Python codec, seconds since the first stamp, ids from 0."""
    config = preset("kitti")
    codes = {name: code for code, name in enumerate(config.class_names)}
    tracker = Tracker(config)
    out = []
    for line in lines:
        payload = encode_detection_frame(
            vehicle="v",
            sensor="s",
            seq=line["seq"],
            stamp_ns=line["stamp_ns"],
            frame_id="lidar",
            boxes=_arrays(line["detections"]),
        )
        decoded = decode_detection_frame(payload, class_codes=codes)
        assert not isinstance(decoded, Rejection), decoded
        frame, _ = frame_from_wire(decoded, (line["stamp_ns"] - lines[0]["stamp_ns"]) * 1e-9)
        t = tracks_to_wire(tracker.step(frame), 0, config.class_names)
        out.append({name: getattr(t, name).tolist() for name in _COMPARED})
    return out


_COMPARED = ("id", "class_index", "center", "size", "yaw", "score", "velocity", "state")


@pytest.mark.zenoh
@BUILDS
@pytest.mark.parametrize("subscribe", ["wide", "owned"])
def test_a_rust_vehicle_is_tracked_as_the_python_core_tracks_it(
    tmp_path: Path, subscribe: str
) -> None:
    # owned: the service subscribes per sensor it finds by the advanced publisher's
    # liveliness token; a vehicle without one would never be heard.
    svc = start_service(
        tmp_path, "--preset", "kitti", env={"SIMPLETRACK_SUBSCRIBE": subscribe}, instance="rust-e2e"
    )
    try:
        lines = _run_publisher(svc.endpoint, f"veh-rust-{subscribe}")
    finally:
        assert svc.stop() == 0
    assert [line["seq"] for line in lines] == list(range(FRAMES))
    unanswered = [line for line in lines if "tracks" not in line]
    assert not unanswered, unanswered[:3]

    # The car starting at x=10 drives along +x: one id from its first frame to its last.
    first_car = []
    for line in lines:
        centers = np.array(line["tracks"]["center"])
        target = np.array(line["detections"]["center"][0])
        first_car.append(
            line["tracks"]["id"][int(np.argmin(np.linalg.norm(centers - target, axis=1)))]
        )
    assert len(set(first_car)) == 1, first_car
    assert sorted({i for line in lines for i in line["tracks"]["id"]}) == [0, 1, 2]

    expected = _python_tracks(lines)
    for line, want in zip(lines, expected, strict=True):
        got = line["tracks"]
        for name in _COMPARED:
            # Exact: the JSON carries each float32 as the float64 it widens to.
            g, w = got[name], want[name]
            assert g == w, f"seq {line['seq']} {name}: rust {g} != python {w}"


@pytest.mark.zenoh
@BUILDS
def test_a_restarted_rust_vehicle_resumes_after_the_services_last_seq(tmp_path: Path) -> None:
    svc = start_service(tmp_path, "--preset", "kitti", instance="rust-resume")
    try:
        first = _run_publisher(svc.endpoint, "veh-rust-resume", frames=5)
        again = _run_publisher(svc.endpoint, "veh-rust-resume", "--resume", frames=5)
        fresh = _run_publisher(svc.endpoint, "veh-rust-resume", frames=2)
    finally:
        assert svc.stop() == 0
    assert [line["seq"] for line in first] == [0, 1, 2, 3, 4]
    # The second run asked the service and went on after its seq 4; every frame tracked.
    assert [line["seq"] for line in again] == [5, 6, 7, 8, 9]
    assert all("tracks" in line for line in again), again
    # Without --resume a restarted publisher starts at 0 again, and is tracked all the same
    # (a new session id tells the service it restarted).
    assert [line["seq"] for line in fresh] == [0, 1]
    assert all("tracks" in line for line in fresh), fresh


@BUILDS
def test_the_rust_fixture_frame_decodes_in_python_as_the_python_encoders() -> None:
    encode_fixture = example("encode_fixture")
    out = subprocess.run([str(encode_fixture)], capture_output=True, text=True, timeout=60)
    assert out.returncode == 0, out.stderr
    payload = bytes.fromhex(out.stdout.strip())
    assert_same_frame(payload, "rust")
    assert payload == reference_payload(), "the same frame should be the same bytes"


def _python_verdict(kind: str, payload: bytes) -> dict[str, Any]:
    if kind == "D":
        r: object = decode_detection_frame(payload)
    elif kind == "T":
        r = decode_track_frame(payload)
    elif kind == "V":
        r = decode_vehicle_track_frame(payload)
    else:
        r = decode_message(payload, FrameError)
    if not isinstance(r, Rejection):
        return {"valid": True}
    return {
        "valid": False,
        "reason": r.reason.value,
        "field": r.field,
        "seq": r.seq,
        "stamp_ns": r.stamp_ns,
    }


@BUILDS
def test_the_rust_decoders_give_the_python_verdict_on_every_payload() -> None:
    """Same acceptance, reason, field and (for a refused frame) seq and stamp on thousands
    of payloads: valid, each field broken in every way, columns at their bounds, damaged."""
    payloads = cases()
    verdicts = example("decode_verdicts")
    stdin = "".join(f"{kind} {payload.hex()}\n" for kind, payload in payloads)
    out = subprocess.run(
        [str(verdicts)], input=stdin, capture_output=True, text=True, timeout=120, check=False
    )
    assert out.returncode == 0, out.stderr
    rust = [json.loads(line) for line in out.stdout.splitlines()]
    assert len(rust) == len(payloads)
    python = [_python_verdict(kind, payload) for kind, payload in payloads]
    differ = [
        (kind, payload.hex()[:120], p, r)
        for (kind, payload), p, r in zip(payloads, python, rust, strict=True)
        if p != r
    ]
    assert not differ, (len(differ), differ[:5])
    refused = sum(1 for p in python if not p["valid"])
    assert 0 < refused < len(python) - 50, (refused, len(python))  # both kinds well covered
