"""A vehicle installs only the client library (no extras) into a fresh virtual environment and
talks to a real service: a detection frame goes out, its tracks come back. The install must not
bring the service's dependencies (scipy, pydantic, prometheus-client, ...)."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import textwrap
from collections.abc import Iterator
from pathlib import Path

import pytest

from tests.service_helpers import ROOT, ServiceProcess, start_service

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
