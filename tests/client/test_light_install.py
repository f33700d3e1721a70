"""A vehicle or an operator installs only the wheel (no extras) into a fresh virtual environment
and talks to a real service: a detection frame goes out, its tracks come back, and the
client-side commands (--version, status, watch, record, replay mcap, view, bridge ros2) run.
The install must not bring the service's dependencies (scipy, pydantic, prometheus-client, ...)
and stays under its size budget (measured as files in the venv, which has no pip)."""

from __future__ import annotations

import contextlib
import json
import os
import signal
import subprocess
import sys
import textwrap
import threading
import time
import urllib.request
from collections.abc import Iterator
from pathlib import Path

import pytest
import zenoh

from simpletrack.spawn import free_port
from tests.service_helpers import ROOT, ServiceProcess, start_service, wait_for

pytestmark = pytest.mark.zenoh
SERVICE_ONLY = ("scipy", "pydantic", "pydantic_settings", "prometheus_client", "yaml", "rich")


def _run(cmd: list[str], **kwargs: object) -> subprocess.CompletedProcess[str]:
    return subprocess.run(cmd, capture_output=True, text=True, timeout=600, **kwargs)  # type: ignore[call-overload]


@pytest.fixture(scope="module")
def light_python(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A fresh venv with the wheel installed without extras (dependencies from the index)."""
    tmp = tmp_path_factory.mktemp("light")
    wheel_dir = tmp / "wheel"
    built = _run(
        [sys.executable, "-m", "pip", "wheel", str(ROOT), "--no-deps", "-q", "-w", str(wheel_dir)]
    )
    assert built.returncode == 0, built.stderr
    venv = tmp / "venv"
    assert _run([sys.executable, "-m", "venv", "--without-pip", str(venv)]).returncode == 0
    python = venv / "bin" / "python"
    wheel = next(wheel_dir.glob("*.whl"))
    # The outer pip installs into the new environment: no pip inside it is needed.
    installed = _run(
        [sys.executable, "-m", "pip", "--python", str(python), "install", "-q",
         "--disable-pip-version-check", str(wheel)]
    )  # fmt: skip
    if installed.returncode != 0 and "Could not find a version" in installed.stderr:
        pytest.skip(f"the package index is not reachable: {installed.stderr[-300:]}")
    assert installed.returncode == 0, installed.stderr
    return python


@pytest.fixture(scope="module")
def service(tmp_path_factory: pytest.TempPathFactory) -> Iterator[ServiceProcess]:
    svc = start_service(tmp_path_factory.mktemp("svc"), instance="light-install")
    yield svc
    svc.stop()


def test_the_client_install_brings_none_of_the_service_dependencies(light_python: Path) -> None:
    probe = f"import importlib.util as u; print([m for m in {SERVICE_ONLY!r} if u.find_spec(m)])"
    out = _run([str(light_python), "-c", probe], cwd="/")
    assert out.returncode == 0, out.stderr
    assert out.stdout.strip() == "[]", f"installed without being asked for: {out.stdout}"


VEHICLE = textwrap.dedent(
    """
    import json, sys, time
    from simpletrack.client import Box, DetectionPublisher, TrackSubscriber, ZenohOptions

    options = ZenohOptions(connect=[sys.argv[1]])
    got = []
    with (
        TrackSubscriber.connect(options=options, vehicle="light", sensor="lidar") as sub,
        DetectionPublisher.connect("light", "lidar", classes=("Car",), options=options) as pub,
    ):
        assert pub.wait_for_service(20), "no service"
        time.sleep(0.3)
        for k in range(3):
            pub.publish([Box(10.0 + k, 0.0, 0.8, 0.0, 4.0, 1.8, 1.6, 0.9, "Car")],
                        stamp_ns=1_700_000_000_000_000_000 + k * 100_000_000)
            msg = sub.recv(timeout=10)
            got.append([int(i) for i in msg.tracks.id])
    print(json.dumps({"ids": got, "modules": sorted(m.split(".")[0] for m in sys.modules)}))
    """
)


def test_a_client_only_vehicle_gets_its_tracks_from_a_real_service(
    light_python: Path, service: ServiceProcess
) -> None:
    env = {k: v for k, v in os.environ.items() if k != "PYTHONPATH"}
    out = _run([str(light_python), "-c", VEHICLE, service.endpoint], cwd="/", env=env)
    assert out.returncode == 0, out.stderr[-2000:]
    result = json.loads(out.stdout.strip().splitlines()[-1])
    assert len(result["ids"]) == 3 and all(len(ids) == 1 for ids in result["ids"])
    assert len({ids[0] for ids in result["ids"]}) == 1, result["ids"]  # one object, one id
    assert not set(SERVICE_ONLY) & set(result["modules"])


def test_the_command_on_a_client_install_names_the_extra_it_needs(light_python: Path) -> None:
    out = _run([str(light_python.parent / "simpletrack"), "serve", "--help"], cwd="/")
    assert out.returncode == 2
    assert "pip install 'simpletrack-service[service]'" in out.stderr, out.stderr
    assert "Traceback" not in out.stderr


# --- the client-side commands on the light install, against the real service ---------------
LIGHT_LIMIT_MB = 120


def _light(light_python: Path, *args: str) -> list[str]:
    return [str(light_python.parent / "simpletrack"), *args]


def _env() -> dict[str, str]:
    return {k: v for k, v in os.environ.items() if k != "PYTHONPATH"} | {"NO_COLOR": "1"}


def _run_light(
    light_python: Path, *args: str, timeout: float = 120
) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        _light(light_python, *args),
        capture_output=True,
        text=True,
        timeout=timeout,
        cwd="/",
        env=_env(),
    )


@contextlib.contextmanager
def _car(service: ServiceProcess, vehicle: str) -> Iterator[list[int]]:
    """A vehicle publishing a car at 10 Hz from this process until the block ends."""
    from simpletrack.client import Box, DetectionPublisher, ZenohOptions

    stop, sent = threading.Event(), [0]
    options = ZenohOptions(connect=[service.endpoint])

    def loop() -> None:
        with DetectionPublisher.connect(vehicle, "lidar", classes=("Car",), options=options) as pub:
            pub.wait_for_service(20)
            while not stop.is_set():
                k = sent[0]
                box = Box(10.0 + k * 0.5, 0.0, 0.8, 0.0, 4.0, 1.8, 1.6, 0.9, "Car")
                pub.publish([box], stamp_ns=time.time_ns())
                sent[0] += 1
                stop.wait(0.1)

    thread = threading.Thread(target=loop, daemon=True)
    thread.start()
    try:
        yield sent
    finally:
        stop.set()
        thread.join(10)


def test_the_light_install_stays_under_its_size_budget(light_python: Path) -> None:
    venv = light_python.parent.parent
    size = sum(f.stat().st_size for f in venv.rglob("*") if f.is_file() and not f.is_symlink())
    assert size < LIGHT_LIMIT_MB * 2**20, f"{size / 2**20:.1f} MB"


def test_version_and_help_need_no_extra(light_python: Path) -> None:
    version = _run_light(light_python, "--version")
    assert version.returncode == 0 and version.stdout.startswith("simpletrack "), version
    helped = _run_light(light_python, "--help")
    assert helped.returncode == 0 and "serve" in helped.stdout and "watch" in helped.stdout


def test_status_lists_the_service(light_python: Path, service: ServiceProcess) -> None:
    out = _run_light(light_python, "status", "--connect", service.endpoint, "--json")
    assert out.returncode == 0, out.stderr
    assert "light-install" in out.stdout


def test_watch_shows_a_vehicle_tracks(light_python: Path, service: ServiceProcess) -> None:
    with _car(service, "light-watch"):
        out = _run_light(
            light_python, "watch", "--connect", service.endpoint,
            "--keys", "fleet/light-watch/*/tracks", "--duration", "4", "--interval", "1",
        )  # fmt: skip
    assert out.returncode == 0, out.stderr
    assert "light-watch/lidar seq" in out.stdout and "1 confirmed" in out.stdout, out.stdout


def test_record_writes_the_tracks_as_json_lines(
    light_python: Path, service: ServiceProcess, tmp_path: Path
) -> None:
    with _car(service, "light-rec"):
        out = _run_light(
            light_python, "record", "--connect", service.endpoint,
            "--keys", "fleet/light-rec/*/tracks", "--out", str(tmp_path), "--frames", "5",
            "--duration", "30", "--quiet",
        )  # fmt: skip
    assert out.returncode == 0, out.stderr
    lines = [json.loads(x) for x in (tmp_path / "tracks.jsonl").read_text().splitlines()]
    assert len(lines) == 5 and {x["vehicle"] for x in lines} == {"light-rec"}
    assert all(len(x["tracks"]) == 1 for x in lines[1:])


def test_record_mcap_names_its_extra(light_python: Path, tmp_path: Path) -> None:
    out = _run_light(
        light_python, "record", "--listen", "tcp/127.0.0.1:0", "--format", "mcap",
        "--out", str(tmp_path / "x.mcap"), "--duration", "1",
    )  # fmt: skip
    assert out.returncode == 2, out
    assert out.stderr.strip().splitlines() == [
        "simpletrack record: needs the mcap extra: pip install 'simpletrack-service[mcap]' "
        "(missing module 'mcap')"
    ]


def test_replay_mcap_sends_a_recording_and_every_frame_is_answered(
    light_python: Path, service: ServiceProcess, tmp_path: Path
) -> None:
    from mcap.writer import Writer

    from simpletrack.wire import encode_detection_frame
    from tests.service_helpers import moving_cars, stamp

    path = tmp_path / "light.mcap"
    with open(path, "wb") as f:  # zstd chunks, as record --format mcap writes them
        w = Writer(f)
        w.start(profile="", library="test")
        channel = w.register_channel(
            "fleet/light-replay/lidar/detections",
            "msgpack",
            w.register_schema("S", "jsonschema", b"{}"),
        )
        for k in range(12):
            payload = encode_detection_frame(
                vehicle="light-replay", sensor="lidar", seq=k, stamp_ns=stamp(k),
                frame_id="lidar", boxes=moving_cars(k),
            )  # fmt: skip
            w.add_message(channel, log_time=stamp(k), data=payload, publish_time=stamp(k))
        w.finish()
    out = _run_light(
        light_python, "replay", "mcap", str(path), "--connect", service.endpoint, "--rate", "max"
    )
    assert out.returncode == 0, out.stderr + out.stdout
    assert "12/12 frames sent" in out.stdout and "12 tracked, 0 refused" in out.stdout, out.stdout


def test_view_serves_a_vehicle_tracks(light_python: Path, service: ServiceProcess) -> None:
    port = free_port()
    proc = subprocess.Popen(
        _light(light_python, "view", "--connect", service.endpoint, "--http-port", str(port)),
        cwd="/", env=_env(), stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
    )  # fmt: skip
    try:
        assert proc.stdout is not None
        assert proc.stdout.readline().startswith("view: http://127.0.0.1:")
        with _car(service, "light-view"):
            url = f"http://127.0.0.1:{port}/state.json"

            def seen() -> bool:
                with urllib.request.urlopen(url, timeout=5) as r:
                    return "light-view/lidar" in json.loads(r.read())["sensors"]

            wait_for(seen, 20, "the vehicle in the view's state")
    finally:
        proc.send_signal(signal.SIGTERM)
        assert proc.wait(30) == 0, proc.stderr.read() if proc.stderr else ""


def test_bridge_ros2_brings_tracked_objects_back(
    light_python: Path, service: ServiceProcess, tmp_path: Path
) -> None:
    from simpletrack.ros2.layout import Layout, topic_keys
    from tests.ros2.bridge_process import Bridge, start_bridge
    from tests.ros2.test_bridge_process import ros_side, run_car

    bridges: list[Bridge] = []
    sessions: list[zenoh.Session] = []
    try:
        bridge = start_bridge(
            bridges, tmp_path, service, "--vehicle", "light-ros", "--sensor", "lidar",
            command=(str(light_python.parent / "simpletrack"),), env=_env(),
        )  # fmt: skip
        keys = topic_keys(Layout.ROS2DDS)
        side = ros_side(sessions, bridge, keys.in_key, keys.out_key, "light-ros")
        run_car(side, 0, 5)
        assert side.n() == 5 and not side.errors
        rc, out = bridge.stop()
        assert rc == 0 and "5 TrackedObjects sent" in out, out
    finally:
        for b in bridges:
            b.kill()
        for s in sessions:
            s.close()  # type: ignore[no-untyped-call]
