"""The C++ codec (clients/cpp): built with CMake outside the checkout, its ctest suite run
(every golden vector both ways), its fixture frame and the example's output read back by the
Python decoder, and its decoder held to the Python decoder's verdicts on mutated payloads.

Needs cmake, a C++17 compiler and the msgpack-c++ and nlohmann/json headers (Debian:
libmsgpack-cxx-dev, nlohmann-json3-dev; scripts/setup.sh installs them in CI). Without them
the tests skip, except under CI=true, where they fail.
"""

from __future__ import annotations

import hashlib
import json
import os
import shutil
import struct
import subprocess
from collections import Counter
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from simpletrack.wire import (
    BoxArrays,
    FrameError,
    Rejection,
    decode_detection_frame,
    decode_message,
    decode_track_frame,
    decode_vehicle_track_frame,
    encode_detection_frame,
)
from simpletrack.wire.codec import pack
from simpletrack.wire.messages import to_map
from tests.native import wire_mutations

pytestmark = [pytest.mark.native, pytest.mark.timeout(900)]

REPO = Path(__file__).resolve().parents[2]
SOURCE = REPO / "clients" / "cpp"
VECTORS = REPO / "schemas" / "vectors"
FIXTURE_JSON = REPO / "tests" / "native" / "fixture_boxes.json"

# The fixture frame both native clients encode (tools/encode_fixture.cpp has the same values).
FIXTURE: dict[str, Any] = {
    "vehicle": "veh-fixture",
    "sensor": "lidar",
    "seq": 7,
    "stamp_ns": 1_700_000_000_000_000_000,
    "frame_id": "base_link",
    "classes": ["Car", "Pedestrian"],
    "class_index": [0, 1, 0],
    "center": [[10, 2, 0.8], [6, -3, 0.9], [25, 4, 0.8]],
    "size": [[4.5, 1.9, 1.6], [0.8, 0.7, 1.8], [4.2, 1.8, 1.5]],
    "yaw": [0.1, 1.5, -0.2],
    "score": [0.9, 0.7, 0.6],
    "velocity": [[5, 0], [1, 0.5], [-3, 0.2]],
}
ACCEPTED = {"Car": 0, "Pedestrian": 1}  # what wire_decode's kind 'D' accepts


def _build_dir() -> Path:
    # One build per checkout: CMake refuses a build directory configured from another source.
    base = Path(
        os.environ.get("SIMPLETRACK_CPP_BUILD", Path.home() / ".cache/simpletrack/cpp-build")
    )
    return base / hashlib.sha256(str(SOURCE).encode()).hexdigest()[:12]


def _missing() -> str | None:
    if shutil.which("cmake") is None:
        return "cmake not found"
    cxx = os.environ.get("CXX") or next(
        (c for c in ("c++", "g++", "clang++") if shutil.which(c)), None
    )
    if cxx is None or shutil.which(cxx) is None:
        return f"no C++ compiler found ({cxx or 'c++, g++ or clang++'})"
    for header, package in (
        ("msgpack.hpp", "libmsgpack-cxx-dev"),
        ("nlohmann/json.hpp", "nlohmann-json3-dev"),
    ):
        probe = subprocess.run(
            [cxx, "-std=c++17", "-DMSGPACK_NO_BOOST", "-E", "-x", "c++", "-", "-o", os.devnull],
            input=f"#include <{header}>\n",
            capture_output=True,
            text=True,
            check=False,
        )
        if probe.returncode != 0:
            return f"{header} not found (Debian: apt-get install {package})"
    return None


def _run(cmd: list[str], cwd: Path | None = None, **kw: Any) -> subprocess.CompletedProcess[str]:
    return subprocess.run(cmd, cwd=cwd, capture_output=True, text=True, check=False, **kw)


@pytest.fixture(scope="module")
def build() -> Path:
    missing = _missing()
    if missing:
        if os.environ.get("CI") == "true":
            pytest.fail(
                f"C++ codec cannot be built: {missing} (in CI, scripts/setup.sh installs the msgpack-c++ and nlohmann-json headers)"
            )
        pytest.skip(f"C++ codec not built: {missing}")
    out = _build_dir()
    configure = ["cmake", "-S", str(SOURCE), "-B", str(out), "-DSIMPLETRACK_WERROR=ON"]
    if not (out / "CMakeCache.txt").exists() and shutil.which("ninja"):
        configure += ["-G", "Ninja"]
    done = _run(configure)
    assert done.returncode == 0, f"cmake configure failed:\n{done.stdout}\n{done.stderr}"
    done = _run(["cmake", "--build", str(out), "-j", "2"])
    assert done.returncode == 0, f"C++ build failed:\n{done.stdout[-6000:]}\n{done.stderr[-3000:]}"
    return out


def test_ctest_checks_every_golden_vector_both_ways(build: Path) -> None:
    done = _run(["ctest", "--output-on-failure", "-V"], cwd=build)
    assert done.returncode == 0, f"ctest failed:\n{done.stdout[-6000:]}\n{done.stderr}"
    assert "100% tests passed" in done.stdout
    vectors = len(list(VECTORS.glob("*.json")))
    assert vectors >= 15
    assert f"checked {vectors} golden vectors" in done.stdout, done.stdout[-3000:]
    assert "golden_vectors: " in done.stdout and " 0 failed" in done.stdout


def _fixture_values() -> dict[str, Any]:
    if FIXTURE_JSON.exists():
        # The Rust client's tests write and read this file: it must hold the values above,
        # which encode_fixture falls back on when the file is absent.
        on_disk = json.loads(FIXTURE_JSON.read_text())
        assert on_disk == FIXTURE, f"{FIXTURE_JSON} differs from the agreed fixture values"
    return FIXTURE


def test_cpp_fixture_frame_is_what_the_python_encoder_writes(build: Path) -> None:
    done = _run([str(build / "encode_fixture")])
    assert done.returncode == 0, done.stderr
    cpp = bytes.fromhex(done.stdout.strip())
    v = _fixture_values()
    boxes = BoxArrays(
        classes=tuple(v["classes"]),
        class_index=np.array(v["class_index"], np.int32),
        center=np.array(v["center"], np.float32),
        size=np.array(v["size"], np.float32),
        yaw=np.array(v["yaw"], np.float32),
        score=np.array(v["score"], np.float64),
        velocity=np.array(v["velocity"], np.float32),
    )
    header = {k: v[k] for k in ("vehicle", "sensor", "seq", "stamp_ns", "frame_id")}
    python = encode_detection_frame(**header, boxes=boxes)

    decoded = decode_detection_frame(cpp)
    assert not isinstance(decoded, Rejection), decoded
    assert decoded.frame.vehicle == "veh-fixture" and decoded.frame.seq == 7
    assert decoded.boxes.class_names() == ["Car", "Pedestrian", "Car"]
    for name in ("class_index", "center", "size", "yaw", "score", "velocity"):
        np.testing.assert_array_equal(
            getattr(decoded.boxes, name), getattr(boxes, name), err_msg=name
        )
    assert cpp == python  # same keys in the same order, same number formats


def test_example_stand_in_puts_frames_the_service_would_accept(build: Path, tmp_path: Path) -> None:
    done = _run([str(build / "publish_with_zenoh"), "--out", str(tmp_path), "--frames", "3"])
    assert done.returncode == 0, done.stderr
    assert done.stdout.count("put fleet/veh-1/lidar/detections (application/msgpack,") == 3
    frames = [
        decode_detection_frame((tmp_path / f"{i}.msgpack").read_bytes(), class_codes=ACCEPTED)
        for i in range(3)
    ]
    assert all(not isinstance(f, Rejection) for f in frames), frames
    seqs = [f.frame.seq for f in frames if not isinstance(f, Rejection)]
    assert seqs == [0, 1, 2]


def _python_verdict(kind: str, payload: bytes) -> tuple[str, Any]:
    """("no", (reason, field, seq, stamp)) or ("ok", the decoded message as a map)."""
    if kind in "dD":
        d = decode_detection_frame(payload, class_codes=ACCEPTED if kind == "D" else None)
        if isinstance(d, Rejection):
            return "no", (d.reason.value, str(d.field), str(d.seq), str(d.stamp_ns))
        return "ok", to_map(d.frame)
    if kind == "t":
        t = decode_track_frame(payload)
        if isinstance(t, Rejection):
            return "no", (t.reason.value, str(t.field), str(t.seq), str(t.stamp_ns))
        return "ok", to_map(t[0])
    if kind == "v":
        v = decode_vehicle_track_frame(payload)
        if isinstance(v, Rejection):
            return "no", (v.reason.value, str(v.field), str(v.seq), str(v.stamp_ns))
        return "ok", to_map(v[0])
    e = decode_message(payload, FrameError)
    if isinstance(e, Rejection):
        return "no", (e.reason.value, str(e.field), str(e.seq), str(e.stamp_ns))
    return "ok", to_map(e)


def test_cpp_decoder_gives_the_python_decoders_verdicts(build: Path) -> None:
    payloads = list(wire_mutations.mutations())
    kinds = "dDtve"
    records = b"".join(k.encode() + struct.pack("<I", len(p)) + p for p in payloads for k in kinds)
    done = subprocess.run(
        [str(build / "wire_decode")], input=records, capture_output=True, check=False
    )
    assert done.returncode == 0, done.stderr.decode()
    lines = done.stdout.decode().splitlines()
    assert len(lines) == len(payloads) * len(kinds)

    mismatches: list[str] = []
    seen: Counter[str] = Counter()
    cases = ((p, k) for p in payloads for k in kinds)
    for (payload, kind), line in zip(cases, lines, strict=True):
        verdict, want = _python_verdict(kind, payload)
        seen[want[0] if verdict == "no" else "ok"] += 1
        got = line.split("\t")
        if verdict == "no":
            same = got[0] == "no" and tuple(got[1:]) == want
        else:
            # The C++ decoder's message, re-encoded, must decode to what Python decoded.
            # Compared packed: a track frame's pose may hold NaN, which != itself.
            again = _python_verdict(kind, bytes.fromhex(got[1])) if got[0] == "ok" else None
            same = again is not None and again[0] == "ok" and pack(again[1]) == pack(want)
        if not same:
            mismatches.append(
                f"{kind} {payload[:48].hex()}...: python {verdict} {want!r:.200}, C++ {line:.200}"
            )
    assert not mismatches, f"{len(mismatches)} of {len(lines)} differ:\n" + "\n".join(
        mismatches[:10]
    )
    # The payloads reach every check, so agreement means something.
    expected = {
        "ok",
        "malformed",
        "too_large",
        "wrong_version",
        "missing_field",
        "wrong_type",
        "invalid_value",
        "extra_field",
        "column_length",
        "non_finite",
        "non_positive_size",
        "unknown_class",
    }
    assert expected <= set(seen), f"never produced: {expected - set(seen)}"
