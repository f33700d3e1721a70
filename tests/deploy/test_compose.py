"""deploy/compose.yaml, the Grafana provisioning and dashboard, and the alert expressions:
every file they name exists, the pieces point at each other, each service instance's
environment is valid settings of one group (same prefix, own instance id, state and port),
and every PromQL query names a metric the service really exports (or the group protocol's)."""

from __future__ import annotations

import json
import os
import re
from pathlib import Path
from typing import Any
from urllib.parse import urlsplit

import pytest
from packaging.specifiers import SpecifierSet

from simpletrack.server.metrics import Metrics
from simpletrack.server.settings import ServiceSettings, load_settings
from simpletrack.sim.demo import DEMO_PRESET
from tests.deploy.helpers import (
    COMPOSE,
    DASHBOARD,
    DEPLOY,
    GROUP_LABELS,
    GROUP_METRICS,
    PROMETHEUS_CONFIG,
    TARGET_LABELS,
    alert_rules,
    dashboard,
    dashboard_queries,
    dependency_spec,
    exported,
    handoff_timeout_s,
    load_yaml,
    matcher_labels,
    promql_names,
)

COMPOSE_DOC: dict[str, Any] = load_yaml(COMPOSE)
SERVICES: dict[str, Any] = COMPOSE_DOC["services"]
# the service instances: every service running the image built from the Dockerfile
TRACKERS = sorted(n for n, s in SERVICES.items() if "build" in s)
OTHERS = {"zenoh-router", "prometheus", "grafana"}


def mounts(service: str) -> dict[str, Path]:
    """container path -> host path of the bind mounts (relative to compose.yaml)."""
    out = {}
    for volume in SERVICES[service].get("volumes", []):
        source, target = volume.split(":")[:2]
        if source.startswith("."):
            out[target] = (COMPOSE.parent / source).resolve()
    return out


def host_file(service: str, container_path: str) -> Path:
    """The host file a container sees at ``container_path`` through a bind mount."""
    for target, source in mounts(service).items():
        if container_path == target or container_path.startswith(target.rstrip("/") + "/"):
            return source / Path(container_path).relative_to(target)
    raise AssertionError(f"{service}: nothing is mounted at {container_path}")


def tracker_settings(monkeypatch: pytest.MonkeyPatch, name: str = "") -> ServiceSettings:
    for key in list(os.environ):
        if key.startswith("SIMPLETRACK_"):
            monkeypatch.delenv(key)
    for key, value in SERVICES[name or TRACKERS[0]]["environment"].items():
        monkeypatch.setenv(key, interpolate(str(value)))
    # The image's own environment (Dockerfile ENV) is under the compose environment.
    monkeypatch.setenv("SIMPLETRACK_METRICS_HOST", "0.0.0.0")
    monkeypatch.setenv("SIMPLETRACK_STATE_DIR", "/var/lib/simpletrack")
    return load_settings()


def interpolate(value: str) -> str:
    """Compose's ``${VAR:-default}`` with VAR unset."""
    return re.sub(r"\$\{\w+:-([^}]*)\}", r"\1", value)


def duration_s(text: str) -> float:
    units = {"ms": 0.001, "s": 1, "m": 60, "h": 3600}
    return sum(float(n) * units[u] for n, u in re.findall(r"(\d+(?:\.\d+)?)(ms|s|m|h)", text))


# ----------------------------------------------------------------------------- compose
def test_compose_runs_a_group_of_service_instances_and_the_rest_once() -> None:
    assert set(SERVICES) == OTHERS | set(TRACKERS)
    assert len(TRACKERS) >= 2, TRACKERS
    images = {SERVICES[n]["image"] for n in TRACKERS}
    assert len(images) == 1, images  # one release in the group


def test_every_file_compose_names_exists() -> None:
    for name in TRACKERS:
        build = SERVICES[name]["build"]
        context = (COMPOSE.parent / build["context"]).resolve()
        assert (context / build["dockerfile"]).is_file()
        assert (context / "pyproject.toml").is_file()
    for service in SERVICES:
        for target, source in mounts(service).items():
            assert source.exists(), f"{service}: {source} (mounted at {target}) does not exist"
    for name in ("zenoh-router", "prometheus", "grafana"):
        assert mounts(name), f"{name} gets its configuration from deploy/"


def test_every_port_is_published_on_loopback_only() -> None:
    for name, service in SERVICES.items():
        for port in service.get("ports", []):
            assert str(port).startswith("127.0.0.1:"), f"{name} publishes {port} on every address"


def test_images_are_pinned_and_the_router_matches_the_zenoh_library() -> None:
    for name, service in SERVICES.items():
        image = service["image"]
        tag = image.rpartition(":")[2]
        assert ":" in image and tag not in {"latest", ""}, f"{name}: {image} is not pinned"
    router_version = SERVICES["zenoh-router"]["image"].rpartition(":")[2]
    assert router_version in SpecifierSet(dependency_spec("eclipse-zenoh"))


@pytest.mark.parametrize("name", TRACKERS)
def test_each_instance_is_a_client_of_the_router(
    monkeypatch: pytest.MonkeyPatch, name: str
) -> None:
    settings = tracker_settings(monkeypatch, name)
    assert settings.preset == DEMO_PRESET  # `simpletrack demo --service external` works
    assert settings.zenoh.mode == "client"
    [endpoint] = settings.zenoh.connect
    host, port = endpoint.removeprefix("tcp/").rsplit(":", 1)
    assert host == "zenoh-router" and host in SERVICES
    router_conf = host_file("zenoh-router", SERVICES["zenoh-router"]["command"][1])
    assert f"tcp/{_router_ip()}:{port}" in router_conf.read_text()
    assert "zenoh-router" in SERVICES[name]["depends_on"]
    assert SERVICES[name].get("restart") == "unless-stopped"  # router not up yet


def test_the_instances_form_one_group(monkeypatch: pytest.MonkeyPatch) -> None:
    """Same prefix and settings but for their identity: own instance id, state volume and
    published metrics port."""
    settings = {name: tracker_settings(monkeypatch, name) for name in TRACKERS}
    identity = {"instance"}
    shared = {n: s.model_dump(exclude=identity) for n, s in settings.items()}
    first = shared[TRACKERS[0]]
    for name, values in shared.items():
        assert values == first, f"{name} differs from {TRACKERS[0]}"
    assert len({s.prefix for s in settings.values()}) == 1
    instances = [s.instance for s in settings.values()]
    assert len(set(instances)) == len(TRACKERS), instances
    assert len({_state_volume(n, settings[n]) for n in TRACKERS}) == len(TRACKERS)
    host_ports = [_published(n, settings[n].metrics_port) for n in TRACKERS]
    assert len(set(host_ports)) == len(TRACKERS), host_ports


def _state_volume(name: str, settings: ServiceSettings) -> str:
    named: dict[str, str] = {
        v.split(":")[1]: v.split(":")[0] for v in SERVICES[name]["volumes"] if not v.startswith(".")
    }
    return named[str(settings.state_dir)]


def _published(name: str, container_port: int) -> str:
    """The host address:port compose publishes a container port on."""
    [published] = [
        p.rpartition(":")[0]
        for p in map(str, SERVICES[name]["ports"])
        if p.rpartition(":")[2] == str(container_port)
    ]
    return published


def _router_ip() -> str:
    return str(SERVICES["zenoh-router"]["networks"]["simpletrack"]["ipv4_address"])


def test_the_router_address_is_on_the_compose_network() -> None:
    import ipaddress

    subnet = COMPOSE_DOC["networks"]["simpletrack"]["ipam"]["config"][0]["subnet"]
    assert ipaddress.ip_address(_router_ip()) in ipaddress.ip_network(subnet)


@pytest.mark.parametrize("name", TRACKERS)
def test_the_stop_grace_period_outlasts_the_drain_and_the_hand_off(
    monkeypatch: pytest.MonkeyPatch, name: str
) -> None:
    settings = tracker_settings(monkeypatch, name)
    service = SERVICES[name]
    assert service["stop_signal"] == "SIGTERM"
    environment = {k: interpolate(str(v)) for k, v in service["environment"].items()}
    drain = settings.shutdown_timeout_s + handoff_timeout_s(settings, environment)
    assert duration_s(service["stop_grace_period"]) >= drain + 10


@pytest.mark.parametrize("name", TRACKERS)
def test_state_is_a_named_volume_at_the_state_dir(
    monkeypatch: pytest.MonkeyPatch, name: str
) -> None:
    settings = tracker_settings(monkeypatch, name)
    assert _state_volume(name, settings) in COMPOSE_DOC["volumes"]


def test_prometheus_scrapes_every_instance_on_its_metrics_port(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    ports = {name: tracker_settings(monkeypatch, name).metrics_port for name in TRACKERS}
    args = SERVICES["prometheus"]["command"]
    config_path = next(a.split("=", 1)[1] for a in args if a.startswith("--config.file="))
    config_file = host_file("prometheus", config_path)
    assert config_file == PROMETHEUS_CONFIG
    jobs = {j["job_name"]: j for j in load_yaml(config_file)["scrape_configs"]}
    targets = [t for sc in jobs["simpletrack"]["static_configs"] for t in sc["targets"]]
    assert sorted(targets) == [f"{name}:{port}" for name, port in ports.items()]
    for rule_file in load_yaml(config_file)["rule_files"]:
        assert (config_file.parent / rule_file).is_file()
    router_targets = [t for sc in jobs["zenoh-router"]["static_configs"] for t in sc["targets"]]
    rest = re.search(r'http_port:\s*"([^"]+)"', (DEPLOY / "zenoh" / "router.json5").read_text())
    assert rest is not None
    host, port = rest.group(1).rsplit(":", 1)
    assert host == _router_ip()
    assert router_targets == [f"zenoh-router:{port}"]


def test_prometheus_serves_the_runbook_at_the_address_it_is_opened_at() -> None:
    """The alerts link to {{ $externalURL }}/consoles/simpletrack-runbook.html: the console
    templates directory is the mounted deploy/prometheus/consoles/, and the external URL is
    the host port Prometheus is published on (tests/deploy/test_prometheus.py has a real
    Prometheus answer the links)."""
    args = SERVICES["prometheus"]["command"]

    def flag(name: str) -> str:
        [value] = [a.split("=", 1)[1] for a in args if a.startswith(f"--{name}=")]
        return interpolate(value)

    consoles = host_file("prometheus", flag("web.console.templates"))
    assert consoles == PROMETHEUS_CONFIG.parent / "consoles"
    for rule in alert_rules():
        url = rule["annotations"]["runbook_url"]
        assert url.startswith("{{ $externalURL }}/consoles/"), url
        assert (
            consoles / url.removeprefix("{{ $externalURL }}/consoles/").partition("#")[0]
        ).is_file()
    external = urlsplit(flag("web.external-url"))
    listen = flag("web.listen-address").rpartition(":")[2]
    published = [p.rsplit(":", 2) for p in SERVICES["prometheus"]["ports"]]
    [(host_ip, host_port)] = [(ip, hp) for ip, hp, cp in published if cp == listen]
    assert external.scheme == "http" and external.path in ("", "/")
    assert external.hostname in ("localhost", host_ip) and str(external.port) == host_port


def test_grafana_is_provisioned_with_the_datasource_and_the_dashboard() -> None:
    provisioning = host_file("grafana", "/etc/grafana/provisioning")
    [datasource] = load_yaml(provisioning / "datasources" / "prometheus.yaml")["datasources"]
    listen = next(
        a for a in SERVICES["prometheus"]["command"] if a.startswith("--web.listen-address=")
    )
    assert datasource["url"] == f"http://prometheus{listen.rpartition('=')[2]}"
    [provider] = load_yaml(provisioning / "dashboards" / "simpletrack.yaml")["providers"]
    dashboards_dir = host_file("grafana", provider["options"]["path"])
    assert DASHBOARD.parent == dashboards_dir
    home = SERVICES["grafana"]["environment"]["GF_DASHBOARDS_DEFAULT_HOME_DASHBOARD_PATH"]
    assert host_file("grafana", home) == DASHBOARD
    # the dashboard's datasource variable defaults to the provisioned datasource
    variables = {v["name"]: v for v in dashboard()["templating"]["list"]}
    assert variables["datasource"]["current"]["value"] == datasource["uid"]


# ----------------------------------------------------------------------------- PromQL names
EXPORTED_NAMES, EXPORTED_LABELS = exported()
KNOWN_NAMES = EXPORTED_NAMES | GROUP_METRICS | {"up"}  # `up` is Prometheus's own, per target
KNOWN_LABELS = EXPORTED_LABELS | GROUP_LABELS | TARGET_LABELS


def test_the_group_metrics_are_what_the_service_exports_once_it_does() -> None:
    if not GROUP_METRICS & EXPORTED_NAMES:
        pytest.skip("the service does not export the group metrics yet")
    assert GROUP_METRICS <= EXPORTED_NAMES, sorted(GROUP_METRICS - EXPORTED_NAMES)
    assert GROUP_LABELS <= EXPORTED_LABELS, sorted(GROUP_LABELS - EXPORTED_LABELS)


def test_the_promql_reader_finds_names_and_labels() -> None:
    names, labels = promql_names(
        'histogram_quantile(0.99, sum by (le, stage) (rate(a_bucket{job="x"}[$__rate_interval])))'
        " / on(instance) group_left sum(b_total offset 5m) > bool 0 and c"
    )
    assert names == {"a_bucket", "b_total", "c"}
    assert labels == {"le", "stage", "instance"}
    assert matcher_labels('x{job="a", instance=~"$instance", reason!="q"}') == {
        "job",
        "instance",
        "reason",
    }


def test_the_dashboard_is_valid_and_every_query_names_an_exported_metric() -> None:
    data = dashboard()
    assert data["uid"] and data["title"] and data["panels"]
    assert len({p["id"] for p in data["panels"]}) == len(data["panels"])
    queries = list(dashboard_queries())
    assert queries
    for title, expr in queries:
        names, labels = promql_names(expr)
        assert names, f"{title}: {expr} selects no metric"
        assert names <= KNOWN_NAMES, f"{title}: {sorted(names - KNOWN_NAMES)} are not exported"
        used = labels | matcher_labels(expr)
        assert used <= KNOWN_LABELS, f"{title}: no label {sorted(used - KNOWN_LABELS)}"


def test_the_dashboard_shows_what_an_operator_needs() -> None:
    text = "\n".join(expr for _, expr in dashboard_queries())
    titles = " ".join(p["title"].lower() for p in dashboard()["panels"])
    for metric in (
        "simpletrack_frames_received_total",
        "simpletrack_frames_tracked_total",
        "simpletrack_frames_rejected_total",
        "simpletrack_frames_dropped_total",
        "simpletrack_active_sensors",
        "simpletrack_active_tracks",
        "simpletrack_snapshot_age_seconds",
    ):
        assert metric in text, metric
    for q in ("0.5", "0.9", "0.99"):
        assert f"histogram_quantile({q}, sum by (le) (rate(simpletrack_end_to_end" in text
    assert "sum by (reason)" in text  # rejects and drops by reason
    for word in ("frame rate", "latency", "rejected", "dropped", "sensors", "tracks", "snapshot"):
        assert word in titles, word


def test_the_dashboard_shows_the_group() -> None:
    queries = list(dashboard_queries())
    text = "\n".join(expr for _, expr in queries)
    for metric in GROUP_METRICS:
        assert metric in text, metric
    per_instance = {expr for _, expr in queries if "sum by (instance)" in expr}
    assert any("simpletrack_active_sensors" in e for e in per_instance)  # owned per instance
    assert any('reason="missed"' in e for e in per_instance)
    assert "sum by (direction)" in text  # hand-offs in and out
    rows = [p for p in dashboard()["panels"] if p["type"] == "row"]
    assert [r["title"] for r in rows] == ["Scale-out group", "Process", "Vehicle fusion"]
    panels = dashboard()["panels"]
    for i, a in enumerate(panels):
        for b in panels[i + 1 :]:
            assert not _overlap(a["gridPos"], b["gridPos"]), f"{a['title']!r} over {b['title']!r}"


# The counters with a vehicle label (metrics_vehicle_label = true).
PER_VEHICLE = (
    "simpletrack_frames_received_total",
    "simpletrack_frames_tracked_total",
    "simpletrack_frames_rejected_total",
    "simpletrack_frames_dropped_total",
    "simpletrack_implausible_frames_total",
    "simpletrack_clock_ahead_frames_total",
)


def test_the_dashboard_filters_the_per_vehicle_counters_by_a_vehicle_variable() -> None:
    variables = {v["name"]: v for v in dashboard()["templating"]["list"]}
    vehicle = variables["vehicle"]
    m = re.fullmatch(r"label_values\((\w+)\{[^}]*\}, (\w+)\)", vehicle["query"]["query"])
    assert m is not None, vehicle["query"]
    assert (m.group(1) in PER_VEHICLE, m.group(2)) == (True, "vehicle")
    # "All" must also match the series without the label (the label is off by default).
    assert vehicle["includeAll"] and vehicle["allValue"] == ".*"
    # Every metric of the service with a vehicle label is one of those.
    labelled = {
        f"{getattr(m, '_name', '')}_total"
        for m in vars(Metrics(vehicle_label=True)).values()
        if "vehicle" in getattr(m, "_labelnames", ())
    }
    assert labelled == set(PER_VEHICLE)
    for title, expr in dashboard_queries():
        for metric in PER_VEHICLE:
            for selector in re.findall(rf"{metric}\{{([^}}]*)\}}", expr):
                assert 'vehicle=~"$vehicle"' in selector, f"{title}: {expr}"
    assert "sensor" not in variables  # no sensor label: unbounded (simpletrack status)


def test_the_dashboard_shows_the_process() -> None:
    by_title = {p["title"]: p for p in dashboard()["panels"]}
    for title, metric in (
        ("CPU per instance", "process_cpu_seconds_total"),
        ("Resident memory per instance", "process_resident_memory_bytes"),
        ("Open file descriptors", "process_open_fds"),
    ):
        [target, *_] = by_title[title]["targets"]
        assert metric in target["expr"] and metric in EXPORTED_NAMES, title
    text = "\n".join(expr for _, expr in dashboard_queries())
    for metric in ("simpletrack_tracker_resets_total", "simpletrack_frames_dropped_total"):
        assert metric in text, metric
    assert 'reason="missed"' in text


def test_the_dashboard_shows_the_fused_vehicles() -> None:
    text = "\n".join(expr for _, expr in dashboard_queries())
    for metric in ("simpletrack_fusion_sensors", "simpletrack_fusion_frames_total"):
        assert metric in text, metric
    assert "sum by (condition)" in text and "sum by (outcome)" in text
    assert "rate(simpletrack_fusion_wait_seconds_bucket" in text


def _overlap(a: dict[str, int], b: dict[str, int]) -> bool:
    return (
        a["x"] < b["x"] + b["w"]
        and b["x"] < a["x"] + a["w"]
        and a["y"] < b["y"] + b["h"]
        and b["y"] < a["y"] + a["h"]
    )


def test_every_alert_names_an_exported_metric() -> None:
    rules = alert_rules()
    assert {r["alert"] for r in rules} >= {
        "SimpletrackDown",
        "SimpletrackNoFrames",
        "SimpletrackLatencyHigh",
        "SimpletrackRejectsRising",
        "SimpletrackSnapshotTooOld",
        "SimpletrackGroupIncomplete",
        "SimpletrackGroupSplit",
        "SimpletrackFailovers",
    }
    for rule in rules:
        names, labels = promql_names(rule["expr"])
        assert names <= KNOWN_NAMES, f"{rule['alert']}: {sorted(names - KNOWN_NAMES)}"
        assert labels | matcher_labels(rule["expr"]) <= KNOWN_LABELS, rule["alert"]
        assert rule["labels"]["severity"] in {"critical", "warning"}
        assert rule["annotations"]["summary"] and rule["annotations"]["description"]


def test_the_dashboard_json_is_formatted_like_it_was_saved() -> None:
    text = DASHBOARD.read_text()
    assert text == json.dumps(json.loads(text), indent=2) + "\n"
