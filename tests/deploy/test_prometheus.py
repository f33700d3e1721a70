"""The Prometheus files in deploy/prometheus/, checked by the real promtool: the scrape config
(with its rule files), the alert rules, and the alerts' unit tests (alerts_test.yml: each alert
fires when it should, for the instance it should, and stays silent otherwise)."""

from __future__ import annotations

import shutil
import subprocess
from pathlib import Path

import pytest

from tests.deploy.helpers import ALERTS, ALERTS_TEST, PROMETHEUS_CONFIG

pytestmark = pytest.mark.system


def promtool(*args: str | Path) -> subprocess.CompletedProcess[str]:
    exe = shutil.which("promtool")
    if exe is None:
        pytest.skip("promtool is not installed (Debian package prometheus)")
    return subprocess.run(
        [exe, *map(str, args)], capture_output=True, text=True, timeout=60, check=False
    )


def test_promtool_accepts_the_scrape_config_and_its_rule_files() -> None:
    out = promtool("check", "config", PROMETHEUS_CONFIG)
    assert out.returncode == 0, out.stdout + out.stderr
    assert "1 rule files found" in out.stdout + out.stderr


def test_promtool_accepts_the_alert_rules() -> None:
    out = promtool("check", "rules", ALERTS)
    assert out.returncode == 0, out.stdout + out.stderr


def test_the_alerts_fire_as_their_unit_tests_say() -> None:
    out = promtool("test", "rules", ALERTS_TEST)
    assert out.returncode == 0, out.stdout + out.stderr


def test_promtool_would_catch_a_broken_rule(tmp_path: Path) -> None:
    broken = tmp_path / "alerts.yml"
    broken.write_text(ALERTS.read_text().replace("> 0.1", "> > 0.1", 1))
    assert promtool("check", "rules", broken).returncode != 0
