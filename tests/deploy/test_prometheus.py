"""The Prometheus files in deploy/prometheus/, checked by the real promtool: the scrape config
(with its rule files), the alert rules, and the alerts' unit tests (alerts_test.yml: each alert
fires when it should, for the instance it should, and stays silent otherwise). And the real
prometheus serving the runbook page the alerts link to (consoles/)."""

from __future__ import annotations

import json
import shutil
import subprocess
import time
import urllib.error
import urllib.request
from pathlib import Path

import pytest

from simpletrack.spawn import free_port
from tests.deploy.helpers import (
    ALERTS,
    ALERTS_TEST,
    COMPOSE,
    PROMETHEUS_CONFIG,
    alert_rules,
    load_yaml,
)

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


def _get(url: str) -> tuple[int, str]:
    try:
        with urllib.request.urlopen(url, timeout=5) as r:
            return int(r.status), r.read().decode()
    except urllib.error.HTTPError as e:
        return e.code, e.read().decode()


def test_prometheus_serves_every_alerts_runbook_link(tmp_path: Path) -> None:
    """A real Prometheus with compose's console flags, the project's rules and a simpletrack
    target nobody listens on (the service is down): SimpletrackDown goes pending with its
    runbook_url expanded to an absolute link, which Prometheus itself answers with the runbook
    page (200); so does every other alert's link, each landing on an id of the page."""
    exe = shutil.which("prometheus")
    if exe is None:
        pytest.skip("prometheus is not installed (Debian package prometheus)")
    port, dead = free_port(), free_port()
    external = f"http://127.0.0.1:{port}"
    config = {
        "global": {"scrape_interval": "1s", "scrape_timeout": "1s", "evaluation_interval": "1s"},
        "rule_files": [str(ALERTS)],
        "scrape_configs": [
            {"job_name": "simpletrack", "static_configs": [{"targets": [f"127.0.0.1:{dead}"]}]}
        ],
    }
    (tmp_path / "prometheus.yml").write_text(json.dumps(config))  # JSON is YAML
    compose = load_yaml(COMPOSE)["services"]["prometheus"]["command"]
    consoles = next(a for a in compose if a.startswith("--web.console.templates="))
    assert consoles == "--web.console.templates=/etc/prometheus/consoles"  # ./prometheus there
    log = tmp_path / "prometheus.log"
    with log.open("wb") as out:
        proc = subprocess.Popen(
            [
                exe,
                f"--config.file={tmp_path / 'prometheus.yml'}",
                f"--storage.tsdb.path={tmp_path / 'data'}",
                f"--web.listen-address=127.0.0.1:{port}",
                f"--web.external-url={external}",
                f"--web.console.templates={PROMETHEUS_CONFIG.parent / 'consoles'}",
                "--log.level=warn",
            ],
            stdout=out,
            stderr=out,
        )
    try:
        down_url = None
        deadline = time.monotonic() + 30
        while down_url is None:
            assert proc.poll() is None, log.read_text()
            assert time.monotonic() < deadline, f"SimpletrackDown never pending\n{log.read_text()}"
            time.sleep(0.5)
            status, body = _get(f"{external}/api/v1/alerts")
            if status != 200:
                continue
            for alert in json.loads(body)["data"]["alerts"]:
                if alert["labels"]["alertname"] == "SimpletrackDown":
                    down_url = alert["annotations"]["runbook_url"]
        assert down_url == f"{external}/consoles/simpletrack-runbook.html#simpletrackdown"
        status, page = _get(down_url.partition("#")[0])
        assert status == 200, page
        assert 'id="simpletrackdown"' in page and "<title>Runbook" in page
        for rule in alert_rules():
            url = rule["annotations"]["runbook_url"].replace("{{ $externalURL }}", external)
            path, _, anchor = url.partition("#")
            status, page = _get(path)
            assert status == 200, url
            assert f'id="{anchor}"' in page, url
    finally:
        proc.terminate()
        try:
            proc.wait(15)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()
