"""A real Prometheus scraping a real service: ``simpletrack serve`` on 127.0.0.1 is fed a short
replay over Zenoh; Prometheus runs the project's scrape config and alert rules (the target
moved to the service's port, 1 s intervals). Through Prometheus's HTTP API: the frame counters,
a latency quantile and the active-tracks gauge are what the replay implies, every dashboard
query evaluates to data, and every alert rule evaluates without error."""

from __future__ import annotations

import json
import math
import shutil
import subprocess
import time
import urllib.error
import urllib.parse
import urllib.request
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import pytest

from tests.deploy.helpers import (
    ALERTS,
    PROMETHEUS_CONFIG,
    alert_rules,
    dashboard_queries,
    grafana_to_promql,
    load_yaml,
)
from tests.service_helpers import (
    ServiceProcess,
    client,
    free_port,
    moving_cars,
    start_service,
    wait_for,
)

pytestmark = [pytest.mark.system, pytest.mark.zenoh]

FRAMES = 20  # 2 s of one sensor at 10 Hz
CARS = 3
JOB = 'job="simpletrack"'


class Prometheus:
    """A Prometheus server on 127.0.0.1 and its HTTP API."""

    def __init__(self, exe: str, config: Path, data: Path, log: Path) -> None:
        self.port = free_port()
        self.log = log
        with log.open("wb") as out:
            self.proc = subprocess.Popen(
                [
                    exe,
                    f"--config.file={config}",
                    f"--storage.tsdb.path={data}",
                    f"--web.listen-address=127.0.0.1:{self.port}",
                    "--log.level=warn",
                ],
                stdout=out,
                stderr=out,
            )

    def api(self, path: str, **params: str) -> Any:
        url = f"http://127.0.0.1:{self.port}{path}?{urllib.parse.urlencode(params)}"
        try:
            with urllib.request.urlopen(url, timeout=5) as r:
                body = json.load(r)
        except urllib.error.HTTPError as e:
            body = json.load(e)
        assert body["status"] == "success", f"{params}: {body}"
        return body["data"]

    def query(self, expr: str) -> list[dict[str, Any]]:
        data = self.api("/api/v1/query", query=expr)
        assert data["resultType"] == "vector", data
        return list(data["result"])

    def value(self, expr: str) -> float:
        result = self.query(expr)
        assert len(result) == 1, f"{expr}: {result}"
        return float(result[0]["value"][1])

    def ready(self) -> bool:
        if self.proc.poll() is not None:
            raise AssertionError(f"prometheus exited:\n{self.log.read_text()}")
        try:
            with urllib.request.urlopen(f"http://127.0.0.1:{self.port}/-/ready", timeout=2) as r:
                return int(r.status) == 200
        except OSError:
            return False

    def stop(self) -> None:
        if self.proc.poll() is None:
            self.proc.terminate()
            try:
                self.proc.wait(15)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait()


def project_config_for(metrics_port: int, tmp: Path) -> Path:
    """deploy/prometheus/prometheus.yml with the simpletrack target on 127.0.0.1 and 1 s
    intervals; its other jobs (the router) do not exist here."""
    config = load_yaml(PROMETHEUS_CONFIG)
    config["global"].update(scrape_interval="1s", scrape_timeout="1s", evaluation_interval="1s")
    [job] = [j for j in config["scrape_configs"] if j["job_name"] == "simpletrack"]
    job["static_configs"] = [{"targets": [f"127.0.0.1:{metrics_port}"]}]
    config["scrape_configs"] = [job]
    config["rule_files"] = [str(PROMETHEUS_CONFIG.parent / f) for f in config["rule_files"]]
    path = tmp / "prometheus.yml"
    path.write_text(json.dumps(config))  # JSON is YAML
    return path


def prometheus_quantile(q: float, buckets: list[tuple[float, float]]) -> float:
    """histogram_quantile as Prometheus computes it from cumulative (le, count) buckets."""
    rank = q * buckets[-1][1]
    b = next((i for i, (_, count) in enumerate(buckets[:-1]) if count >= rank), len(buckets) - 1)
    if b == len(buckets) - 1:
        return buckets[-2][0]
    start, below = (0.0, 0.0) if b == 0 else buckets[b - 1]
    end, count = buckets[b]
    return start + (end - start) * (rank - below) / (count - below)


def buckets_of(metrics: dict[str, float], name: str) -> list[tuple[float, float]]:
    out = []
    for key, value in metrics.items():
        if key.startswith(f"{name}_bucket{{"):
            le = key.split('le="')[1].split('"')[0]
            out.append((math.inf if le == "+Inf" else float(le), value))
    return sorted(out)


def replay(service: ServiceProcess) -> int:
    """FRAMES frames of CARS cars at 10 Hz stamped with the wall clock, then the last frame
    again (a duplicate seq, rejected). Returns the number of tracks on the last frame."""
    with client(service.endpoint) as cli:
        t0 = time.monotonic()
        for k in range(FRAMES):
            time.sleep(max(0.0, t0 + 0.1 * k - time.monotonic()))
            stamp = time.time_ns()
            cli.send("veh-1", "lidar", seq=k, stamp_ns=stamp, boxes=moving_cars(k, n=CARS))
        cli.send("veh-1", "lidar", seq=FRAMES - 1, stamp_ns=stamp, boxes=moving_cars(k, n=CARS))
        wait_for(lambda: cli.received.n_tracks("veh-1/lidar") == FRAMES, 20, "every track frame")
        wait_for(lambda: cli.received.n_errors("veh-1/lidar") == 1, 20, "the duplicate's error")
        _, last = cli.received.tracks["veh-1/lidar"][-1]
        return len(last.id)


@dataclass
class Scraped:
    service: ServiceProcess
    prometheus: Prometheus
    last_tracks: int


@pytest.fixture(scope="module")
def scraped(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Scraped]:
    """One service, one Prometheus scraping it, one replay: shared by the tests below."""
    exe = shutil.which("prometheus")
    if exe is None:
        pytest.skip("prometheus is not installed (Debian package prometheus)")
    tmp = tmp_path_factory.mktemp("prometheus-e2e")
    service = start_service(tmp, "--state-dir", str(tmp / "state"), instance="prom-e2e")
    prom: Prometheus | None = None
    try:
        config = project_config_for(service.metrics_port, tmp)
        prom = Prometheus(exe, config, tmp / "tsdb", tmp / "prometheus.log")
        last_tracks = replay(service)  # while Prometheus starts
        wait_for(prom.ready, 30, "prometheus ready")
        yield Scraped(service, prom, last_tracks)
    finally:
        if prom is not None:
            prom.stop()
        service.stop()


def test_prometheus_sees_what_the_replay_did(scraped: Scraped) -> None:
    service, prometheus, last_tracks = scraped.service, scraped.prometheus, scraped.last_tracks
    assert last_tracks == CARS  # three cars driving in a row: three tracks
    done = f"simpletrack_end_to_end_seconds_count{{{JOB}}} == {FRAMES}"
    wait_for(lambda: bool(prometheus.query(done)), 30, f"a scrape showing {FRAMES} frames")

    assert prometheus.value(f"simpletrack_frames_received_total{{{JOB}}}") == FRAMES + 1
    assert prometheus.value(f"simpletrack_frames_tracked_total{{{JOB}}}") == FRAMES
    rejected = prometheus.query(f"sum by (reason) (simpletrack_frames_rejected_total{{{JOB}}}) > 0")
    assert {r["metric"]["reason"]: float(r["value"][1]) for r in rejected} == {"duplicate_seq": 1.0}
    assert prometheus.value(f"sum(simpletrack_frames_dropped_total{{{JOB}}})") == 0
    assert prometheus.value(f"simpletrack_active_tracks{{{JOB}}}") == last_tracks
    assert prometheus.value(f"simpletrack_active_sensors{{{JOB}}}") == 1

    # The p99 of end-to-end latency, from the same buckets the service exports.
    buckets = buckets_of(service.metrics(), "simpletrack_end_to_end_seconds")
    assert buckets[-1] == (math.inf, FRAMES)
    p99 = prometheus.value(
        f"histogram_quantile(0.99, sum by (le) (simpletrack_end_to_end_seconds_bucket{{{JOB}}}))"
    )
    assert p99 == pytest.approx(prometheus_quantile(0.99, buckets), rel=1e-9)
    assert 0 < p99 <= buckets[-2][0]
    print(f"end-to-end p99 {p99 * 1e3:.2f} ms from buckets {buckets}")


def test_every_dashboard_query_and_alert_rule_works_on_real_data(scraped: Scraped) -> None:
    prometheus = scraped.prometheus
    # rate() needs two samples in its window: wait for a few scrapes of the final state
    scrapes = f"count_over_time(simpletrack_frames_tracked_total{{{JOB}}}[1m]) >= 3"
    wait_for(lambda: bool(prometheus.query(scrapes)), 30, "three scrapes")
    for title, expr in dashboard_queries():
        result = prometheus.query(grafana_to_promql(expr))
        assert result, f"panel {title!r}: {expr} returned no series"

    names = {r["alert"] for r in alert_rules()}

    def evaluated() -> list[dict[str, Any]]:
        groups = prometheus.api("/api/v1/rules")["groups"]
        return [r for g in groups for r in g["rules"] if not r["lastEvaluation"].startswith("0001")]

    wait_for(lambda: {r["name"] for r in evaluated()} == names, 30, "every rule evaluated")
    for rule in evaluated():
        assert rule["health"] == "ok", rule
    assert str(ALERTS.parent) in str(prometheus.api("/api/v1/status/config")["yaml"])
