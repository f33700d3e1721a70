"""deploy/k8s/: the manifests parse, name files that exist, point at each other, probe paths
the service really serves, run one group of replicas on one prefix (PDB, rolling update,
spread over nodes, every replica scraped), and give it valid settings and enough time to drain,
hand its sensors over and snapshot on SIGTERM."""

from __future__ import annotations

import os
import re
import tomllib
import urllib.error
import urllib.request
from pathlib import Path
from typing import Any

import pytest

from simpletrack.cli.main import build_parser
from simpletrack.server.metrics import HttpEndpoint, Metrics
from simpletrack.server.settings import ServiceSettings, load_settings
from tests.deploy.helpers import (
    ALERTS,
    COMPOSE,
    DEPLOY,
    K8S,
    alert_rules,
    handoff_timeout_s,
    load_yaml,
    load_yaml_all,
    project_version,
)

KUSTOMIZATION: dict[str, Any] = load_yaml(K8S / "kustomization.yaml")
RUNBOOK_KUSTOMIZATION = K8S / "prometheus-runbook" / "kustomization.yaml"
DOCS: list[dict[str, Any]] = [
    doc for name in KUSTOMIZATION["resources"] for doc in load_yaml_all(K8S / name)
]


def one(kind: str, name: str) -> dict[str, Any]:
    found = [d for d in DOCS if d["kind"] == kind and d["metadata"]["name"] == name]
    assert len(found) == 1, f"{kind}/{name}: {len(found)} found"
    return found[0]


def generated(name: str) -> dict[str, Path]:
    """key in the ConfigMap -> file, for a configMapGenerator entry."""
    [gen] = [g for g in KUSTOMIZATION["configMapGenerator"] if g["name"] == name]
    out = {}
    for entry in gen["files"]:
        key, _, path = entry.rpartition("=") if "=" in entry else (entry, "", entry)
        out[key or Path(path).name] = K8S / path
    return out


def container(workload: dict[str, Any]) -> dict[str, Any]:
    [c] = workload["spec"]["template"]["spec"]["containers"]
    assert isinstance(c, dict)
    return c


def mounted_file(workload: dict[str, Any], path: str) -> Path:
    """The generated ConfigMap file a container sees at ``path``."""
    spec = workload["spec"]["template"]["spec"]
    volumes = {v["name"]: v for v in spec["volumes"]}
    for mount in container(workload)["volumeMounts"]:
        if path.startswith(mount["mountPath"].rstrip("/") + "/"):
            config_map = volumes[mount["name"]]["configMap"]["name"]
            return generated(config_map)[Path(path).relative_to(mount["mountPath"]).as_posix()]
    raise AssertionError(f"nothing mounted at {path}")


TRACKER = one("StatefulSet", "simpletrack")
ROUTER = one("Deployment", "zenoh-router")


def tracker_settings(monkeypatch: pytest.MonkeyPatch) -> ServiceSettings:
    for key in list(os.environ):
        if key.startswith("SIMPLETRACK_"):
            monkeypatch.delenv(key)
    for env in container(TRACKER).get("env", []):
        if env["name"].startswith("SIMPLETRACK_"):
            # downward-API values: what the kubelet would put there
            monkeypatch.setenv(env["name"], env.get("value", "simpletrack-0"))
    args = build_parser().parse_args(container(TRACKER)["args"])
    return load_settings(mounted_file(TRACKER, str(args.config)))


def test_every_manifest_parses_and_names_existing_files() -> None:
    for name in KUSTOMIZATION["resources"]:
        assert (K8S / name).is_file(), name
    for gen in KUSTOMIZATION["configMapGenerator"]:
        for path in generated(gen["name"]).values():
            assert path.is_file(), path
    for doc in DOCS:
        assert doc["apiVersion"] and doc["kind"] and doc["metadata"]["name"], doc
    kinds = {d["kind"] for d in DOCS}
    assert kinds >= {
        "StatefulSet",
        "Deployment",
        "Service",
        "ServiceMonitor",
        "PrometheusRule",
        "NetworkPolicy",
    }


def test_the_service_command_and_config_file_are_valid(monkeypatch: pytest.MonkeyPatch) -> None:
    args = build_parser().parse_args(container(TRACKER)["args"])
    assert args.command == "serve"
    settings = tracker_settings(monkeypatch)
    assert settings.instance == "simpletrack-0"  # from the pod name
    assert settings.metrics_host == "0.0.0.0"
    assert settings.zenoh.mode == "client"
    router_service = one("Service", "zenoh-router")
    ports = {p["port"] for p in router_service["spec"]["ports"]}
    for endpoint in settings.zenoh.connect:
        host, port = endpoint.removeprefix("tcp/").rsplit(":", 1)
        assert host == router_service["metadata"]["name"] and int(port) in ports


def _named_port(workload: dict[str, Any], port: str | int) -> int:
    if isinstance(port, int):
        return port
    [p] = [p for p in container(workload)["ports"] if p["name"] == port]
    return int(p["containerPort"])


def _http_probes() -> list[tuple[str, dict[str, Any]]]:
    c = container(TRACKER)
    return [
        (kind, c[kind]["httpGet"])
        for kind in ("startupProbe", "livenessProbe", "readinessProbe")
        if kind in c
    ]


def test_probes_hit_paths_the_service_serves_on_its_metrics_port(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    settings = tracker_settings(monkeypatch)
    probes = _http_probes()
    assert {kind for kind, _ in probes} >= {"livenessProbe", "readinessProbe"}
    paths = {kind: get["path"] for kind, get in probes}
    assert paths["livenessProbe"] == "/healthz" and paths["readinessProbe"] == "/readyz"
    for _, get in probes:
        assert _named_port(TRACKER, get["port"]) == settings.metrics_port
    ready = [False]
    endpoint = HttpEndpoint(Metrics(), "127.0.0.1", 0, ready=lambda: ready[0])
    endpoint.start()
    try:
        status = {p: _status(endpoint.port, p) for p in set(paths.values())}
        assert status == {"/healthz": 200, "/readyz": 503}  # alive, not ready yet
        ready[0] = True
        assert _status(endpoint.port, "/readyz") == 200
    finally:
        endpoint.close()


def _status(port: int, path: str) -> int:
    try:
        with urllib.request.urlopen(f"http://127.0.0.1:{port}{path}", timeout=5) as r:
            return int(r.status)
    except urllib.error.HTTPError as e:
        return int(e.code)


def test_the_grace_period_outlasts_the_drain_and_the_hand_off(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    settings = tracker_settings(monkeypatch)
    args = build_parser().parse_args(container(TRACKER)["args"])
    config = tomllib.loads(mounted_file(TRACKER, str(args.config)).read_text())
    env = {e["name"]: e["value"] for e in container(TRACKER).get("env", []) if "value" in e}
    drain = settings.shutdown_timeout_s + handoff_timeout_s(settings, {**config, **env})
    grace = TRACKER["spec"]["template"]["spec"]["terminationGracePeriodSeconds"]
    assert grace >= drain + 10


def test_one_statefulset_runs_the_group_on_one_prefix(monkeypatch: pytest.MonkeyPatch) -> None:
    workloads = [d for d in DOCS if d["kind"] in {"StatefulSet", "Deployment"}]
    trackers = [w for w in workloads if container(w)["image"] == "simpletrack-service"]
    assert trackers == [TRACKER]  # no StatefulSet per prefix
    spec = TRACKER["spec"]
    assert spec["replicas"] >= 2
    assert spec["updateStrategy"]["type"] == "RollingUpdate"
    assert spec.get("podManagementPolicy", "OrderedReady") == "Parallel"
    env = {e["name"]: e for e in container(TRACKER)["env"]}
    # the pod name is the member name
    assert env["SIMPLETRACK_INSTANCE"]["valueFrom"]["fieldRef"]["fieldPath"] == "metadata.name"
    assert "SIMPLETRACK_PREFIX" not in env
    assert tracker_settings(monkeypatch).prefix  # one prefix, from simpletrack.toml


def _selects(selector: dict[str, Any], labels: dict[str, str]) -> bool:
    assert set(selector) == {"matchLabels"}, selector  # no matchExpressions to evaluate here
    return bool(selector["matchLabels"].items() <= labels.items())


def test_the_disruption_budget_takes_one_tracker_pod_at_a_time() -> None:
    pdb = one("PodDisruptionBudget", "simpletrack")
    assert pdb["spec"]["maxUnavailable"] == 1 and "minAvailable" not in pdb["spec"]
    selector = pdb["spec"]["selector"]
    assert selector == TRACKER["spec"]["selector"]  # the same pods as the StatefulSet
    assert _selects(selector, TRACKER["spec"]["template"]["metadata"]["labels"])
    assert not _selects(selector, ROUTER["spec"]["template"]["metadata"]["labels"])
    # while one pod is disrupted, the others can still hold an owner and a standby
    assert TRACKER["spec"]["replicas"] - pdb["spec"]["maxUnavailable"] >= 2


def test_replicas_prefer_different_nodes() -> None:
    anti = TRACKER["spec"]["template"]["spec"]["affinity"]["podAntiAffinity"]
    assert "requiredDuringSchedulingIgnoredDuringExecution" not in anti  # fewer nodes: still runs
    [term] = anti["preferredDuringSchedulingIgnoredDuringExecution"]
    affinity = term["podAffinityTerm"]
    assert affinity["topologyKey"] == "kubernetes.io/hostname"
    assert _selects(affinity["labelSelector"], TRACKER["spec"]["template"]["metadata"]["labels"])


def test_the_member_alert_expects_the_replicas_and_the_compose_instances() -> None:
    [rule] = [r for r in alert_rules() if r["alert"] == "SimpletrackGroupIncomplete"]
    expected = re.fullmatch(r"max\(simpletrack_group_members\{[^}]*\}\) < (\d+)", rule["expr"])
    assert expected is not None, rule["expr"]
    assert int(expected.group(1)) == TRACKER["spec"]["replicas"]
    assert f"of {expected.group(1)} members" in rule["annotations"]["summary"]
    compose_trackers = [s for s in load_yaml(COMPOSE)["services"].values() if "build" in s]
    assert len(compose_trackers) == TRACKER["spec"]["replicas"]


def test_every_file_of_the_directory_is_applied() -> None:
    listed = set(KUSTOMIZATION["resources"])
    generated_files = {
        p.name for g in KUSTOMIZATION["configMapGenerator"] for p in generated(g["name"]).values()
    }
    for path in K8S.iterdir():
        if path.name == "kustomization.yaml" or path == RUNBOOK_KUSTOMIZATION.parent:
            continue  # the runbook's kustomization goes to Prometheus's namespace
        assert path.name in listed | generated_files, f"{path.name} is not in kustomization.yaml"


def test_the_runbook_configmap_holds_the_page_prometheus_serves() -> None:
    """deploy/k8s/prometheus-runbook/: one ConfigMap, named without a hash suffix (the
    Prometheus resource's volume names it), holding the runbook page under the file name the
    alerts' runbook_url ends in."""
    kustomization = load_yaml(RUNBOOK_KUSTOMIZATION)
    [gen] = kustomization["configMapGenerator"]
    assert gen["options"]["disableNameSuffixHash"] is True
    assert gen["files"] == ["simpletrack-runbook.html"]
    assert set(kustomization) <= {"apiVersion", "kind", "namespace", "labels", "configMapGenerator"}
    page = RUNBOOK_KUSTOMIZATION.parent / gen["files"][0]
    assert page.read_text() == (DEPLOY / "prometheus" / "consoles" / page.name).read_text()
    comment = RUNBOOK_KUSTOMIZATION.read_text()
    assert f"name: {gen['name']}" in comment and f"/etc/prometheus/consoles/{page.name}" in comment
    for rule in alert_rules(load_yaml(K8S / "prometheusrule.yaml")["spec"]):
        assert f"/consoles/{page.name}#" in rule["annotations"]["runbook_url"]


def test_state_lives_on_a_persistent_volume(monkeypatch: pytest.MonkeyPatch) -> None:
    settings = tracker_settings(monkeypatch)
    claims = {c["metadata"]["name"] for c in TRACKER["spec"]["volumeClaimTemplates"]}
    mounts = {m["mountPath"]: m["name"] for m in container(TRACKER)["volumeMounts"]}
    assert mounts[str(settings.state_dir)] in claims


def test_the_pods_are_bounded_and_unprivileged() -> None:
    dockerfile = (Path(__file__).resolve().parents[2] / "Dockerfile").read_text()
    uid = re.search(r"ARG APP_UID=(\d+)", dockerfile)
    assert uid is not None
    for workload in (TRACKER, ROUTER):
        c = container(workload)
        assert c["resources"]["requests"]["cpu"] and c["resources"]["requests"]["memory"]
        assert c["resources"]["limits"]["memory"]
        assert c["securityContext"]["allowPrivilegeEscalation"] is False
        assert c["securityContext"]["capabilities"]["drop"] == ["ALL"]
        assert workload["spec"]["template"]["spec"]["securityContext"]["runAsNonRoot"] is True
    pod = TRACKER["spec"]["template"]["spec"]["securityContext"]
    assert pod["runAsUser"] == int(uid.group(1)) == pod["fsGroup"]  # the image's user owns state
    assert container(TRACKER)["resources"]["limits"]["cpu"]


def test_the_service_monitor_scrapes_every_replica_as_job_simpletrack() -> None:
    service = one("Service", "simpletrack")
    pod_labels = TRACKER["spec"]["template"]["metadata"]["labels"]
    assert service["spec"]["selector"].items() <= pod_labels.items()
    assert service["spec"]["clusterIP"] == "None"  # headless: one endpoint per pod, no proxy
    assert TRACKER["spec"]["serviceName"] == "simpletrack"
    monitor = one("ServiceMonitor", "simpletrack")
    assert (
        monitor["spec"]["selector"]["matchLabels"].items() <= service["metadata"]["labels"].items()
    )
    port_names = {p["name"] for p in service["spec"]["ports"]}
    [endpoint] = monitor["spec"]["endpoints"]
    assert endpoint["port"] in port_names and endpoint["path"] == "/metrics"
    # `instance` is the pod name, which is the member name of the group
    relabel = {r["targetLabel"]: r["sourceLabels"] for r in endpoint.get("relabelings", [])}
    assert relabel["instance"] == ["__meta_kubernetes_pod_name"]
    # the job label is the Service's name; alerts and the dashboard select job="simpletrack"
    assert 'job="simpletrack"' in ALERTS.read_text()


def test_the_prometheus_rule_carries_the_same_alerts() -> None:
    rule = one("PrometheusRule", "simpletrack")
    assert rule["spec"] == load_yaml(ALERTS)


def test_the_router_listens_on_the_pod_address_only() -> None:
    c = container(ROUTER)
    args = c["args"]
    listen = args[args.index("--listen") + 1]
    assert listen == "tcp/$(POD_IP):7447"
    env = {e["name"]: e for e in c["env"]}
    assert env["POD_IP"]["valueFrom"]["fieldRef"]["fieldPath"] == "status.podIP"
    assert mounted_file(ROUTER, args[args.index("-c") + 1]).is_file()
    service = one("Service", "zenoh-router")
    assert {_named_port(ROUTER, p["targetPort"]) for p in service["spec"]["ports"]} == {7447}
    assert (
        service["spec"]["selector"].items()
        <= ROUTER["spec"]["template"]["metadata"]["labels"].items()
    )


def test_images_match_the_project_and_compose() -> None:
    [image] = KUSTOMIZATION["images"]
    assert image["name"] == container(TRACKER)["image"]
    assert image["newTag"] == project_version()
    # The registry's one place: the manifests never name one themselves.
    assert image["newName"].rpartition("/")[2] == "simpletrack-service"
    assert "/" not in container(TRACKER)["image"] and ":" not in container(TRACKER)["image"]
    assert "poddisruptionbudget.yaml" in KUSTOMIZATION["resources"]
    compose = load_yaml(COMPOSE)
    assert container(ROUTER)["image"] == compose["services"]["zenoh-router"]["image"]
