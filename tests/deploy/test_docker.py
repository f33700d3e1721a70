"""The Dockerfile, checked without a Docker engine: its structure (scripts/check_dockerfile.py,
which also builds and runs it on the host: too slow for the suite), its HEALTHCHECK against the
service's real HTTP endpoint, its command and its environment against the real CLI and settings.
"""

from __future__ import annotations

import importlib.util
import os
import subprocess
import sys
from pathlib import Path
from types import ModuleType

import pytest

from simpletrack.cli.main import build_parser
from simpletrack.server.metrics import HttpEndpoint, Metrics
from simpletrack.server.settings import load_settings
from tests.deploy.helpers import ROOT


def _checker() -> ModuleType:
    spec = importlib.util.spec_from_file_location(
        "check_dockerfile", ROOT / "scripts" / "check_dockerfile.py"
    )
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module  # dataclasses look their module up
    spec.loader.exec_module(module)
    return module


check = _checker()
DOCKERFILE = (ROOT / "Dockerfile").read_text()


def test_the_dockerfile_passes_every_static_check() -> None:
    assert check.static_problems(check.parse(DOCKERFILE)) == []


@pytest.mark.parametrize(
    ("edit", "problem"),
    [
        (("USER ${APP_UID}:${APP_UID}\n", ""), "no USER"),
        (("USER ${APP_UID}:${APP_UID}", "USER root"), "is root"),
        (("%s/healthz'", "%s/metrics'"), "HEALTHCHECK"),
        (("HEALTHCHECK --interval", "# HEALTHCHECK --interval"), "HEALTHCHECK"),
        (("EXPOSE 9464 7447", "EXPOSE 7447"), "metrics port"),
        (("STOPSIGNAL SIGTERM", "STOPSIGNAL SIGKILL"), "STOPSIGNAL"),
        (('VOLUME ["/var/lib/simpletrack"]', 'VOLUME ["/data"]'), "VOLUME"),
        (("COPY clients ./clients", "COPY clientz ./clients"), "does not exist"),
        (("COPY clients ./clients", "COPY tests ./tests"), "excluded by .dockerignore"),
        (("python:3.11-slim-bookworm", "python:3.11-bookworm"), "slim Python 3.11"),
        (
            ("COPY pyproject.toml ./\n", "COPY service ./service\nCOPY pyproject.toml ./\n"),
            "before",
        ),
    ],
)
def test_the_checker_catches_each_mistake(edit: tuple[str, str], problem: str) -> None:
    old, new = edit
    assert old in DOCKERFILE
    problems = check.static_problems(check.parse(DOCKERFILE.replace(old, new, 1)))
    assert any(problem in p for p in problems), problems


def test_dockerignore_keeps_local_state_out_of_the_build_context() -> None:
    patterns = check.read_dockerignore(ROOT)
    for path in (".venv", ".git", "state", "out", "tests", "service/__pycache__", ".env"):
        assert check.ignored(path, patterns), path
    for path in (
        "pyproject.toml",
        "README.md",
        "service/simpletrack/server/app.py",
        "schemas/json",
        "clients",
    ):
        assert not check.ignored(path, patterns), path


def test_the_image_command_is_a_real_subcommand() -> None:
    argv = check.command_line(check.parse(DOCKERFILE))
    assert argv[0] == "simpletrack"  # the console script of pyproject.toml
    args = build_parser().parse_args(argv[1:])
    assert args.command == "serve"


def test_the_image_environment_is_valid_settings(monkeypatch: pytest.MonkeyPatch) -> None:
    df = check.parse(DOCKERFILE)
    env = check.stage_env(df, df.stages[-1])
    ours = {k: v for k, v in env.items() if k.startswith("SIMPLETRACK_")}
    assert ours, "the image configures the service through SIMPLETRACK_* variables"
    for key in list(os.environ):
        if key.startswith("SIMPLETRACK_"):
            monkeypatch.delenv(key)
    for key, value in ours.items():
        monkeypatch.setenv(key, value)
    settings = load_settings()
    assert settings.metrics_host == "0.0.0.0"  # reachable from outside the container
    assert str(settings.state_dir) in {
        v for i in df.stages[-1].all("VOLUME") for v in i.exec_form()
    }
    assert str(settings.metrics_port) in df.stages[-1].last("EXPOSE").args.split()
    assert settings.zenoh.listen == ["tcp/127.0.0.1:7447"]  # nothing reachable until configured


def test_the_healthcheck_command_passes_exactly_while_the_service_answers(tmp_path: Path) -> None:
    argv = check.healthcheck_argv(check.parse(DOCKERFILE))
    assert argv[0] == "python"  # the image's interpreter: slim images have no curl
    endpoint = HttpEndpoint(Metrics(), "127.0.0.1", 0, ready=lambda: False)
    endpoint.start()
    env = {"SIMPLETRACK_METRICS_PORT": str(endpoint.port)}

    def healthcheck() -> int:
        return subprocess.call(
            [sys.executable, *argv[1:]], env=env, stderr=subprocess.DEVNULL, timeout=30
        )

    try:
        assert healthcheck() == 0  # alive even while not ready (/healthz, not /readyz)
    finally:
        endpoint.close()
    assert healthcheck() == 1  # unhealthy (2 would be reserved)
