"""What the deployment tests share: the files under deploy/, the metric names the service
really exports (and the group protocol's, announced before it exports them), the grace a
stopping instance needs, and a small PromQL reader (names and grouping labels of an
expression)."""

from __future__ import annotations

import json
import re
import tomllib
from collections.abc import Iterator, Mapping
from pathlib import Path
from typing import Any

import yaml

from simpletrack.server.metrics import Metrics
from simpletrack.server.settings import ServiceSettings

ROOT = Path(__file__).resolve().parents[2]
DEPLOY = ROOT / "deploy"
COMPOSE = DEPLOY / "compose.yaml"
PROMETHEUS_CONFIG = DEPLOY / "prometheus" / "prometheus.yml"
ALERTS = DEPLOY / "prometheus" / "alerts.yml"
ALERTS_TEST = DEPLOY / "prometheus" / "alerts_test.yml"
DASHBOARD = DEPLOY / "grafana" / "dashboards" / "simpletrack.json"
K8S = DEPLOY / "k8s"

# Labels Prometheus adds to every target's series.
TARGET_LABELS = frozenset({"job", "instance"})

# The scale-out group's metrics and labels (docs/DEPLOY.md, "Scale-out"): the dashboard and the
# alerts use them before the service exports them; test_compose.py checks this list against
# the service's registry as soon as it exports any of them.
GROUP_METRICS = frozenset(
    {
        "simpletrack_group_members",
        "simpletrack_standby_sensors",
        "simpletrack_handoffs_total",
        "simpletrack_failovers_total",
        "simpletrack_replayed_frames_total",
        "simpletrack_frames_not_owned_total",
        "simpletrack_checkpoints_sent_total",
    }
)
GROUP_LABELS = frozenset({"direction"})
# handoff_timeout_s of the group protocol, until the settings have it
HANDOFF_TIMEOUT_DEFAULT_S = 1.0
_KEYWORDS = frozenset(
    {"and", "or", "unless", "bool", "offset", "by", "without", "on", "ignoring", "Inf", "NaN"}
    | {"group_left", "group_right"}
)
_GROUPING = re.compile(r"\b(by|without|on|ignoring|group_left|group_right)\s*\(([^)]*)\)")


def exported() -> tuple[set[str], set[str]]:
    """Sample names and label names of a fresh ``Metrics`` registry, i.e. what /metrics shows
    (with ``metrics_vehicle_label`` on, so that its label is known too)."""
    names: set[str] = set()
    labels: set[str] = set()
    for metrics in (Metrics(), Metrics(vehicle_label=True)):
        metrics.count_received("v")  # labelled counters show their samples once used
        for family in metrics.registry.collect():
            names.add(family.name)
            for sample in family.samples:
                names.add(sample.name)
                labels.update(sample.labels)
    return names, labels


def handoff_timeout_s(settings: ServiceSettings, sources: Mapping[str, Any]) -> float:
    """How long a stopping instance answers hand-off queries: the settings' value once the
    service has the setting; until then what the deployment sets (``SIMPLETRACK_*`` env or
    settings-file key in ``sources``), else the protocol's default."""
    if "handoff_timeout_s" in ServiceSettings.model_fields:
        return float(settings.model_dump()["handoff_timeout_s"])
    value = sources.get("SIMPLETRACK_HANDOFF_TIMEOUT_S", sources.get("handoff_timeout_s"))
    return HANDOFF_TIMEOUT_DEFAULT_S if value is None else float(value)


def promql_names(expr: str) -> tuple[set[str], set[str]]:
    """The metric names an expression selects, and the labels it groups or matches by."""
    text = re.sub(r'"(?:[^"\\]|\\.)*"', '""', expr)  # string literals
    text = re.sub(r"\{[^}]*\}", "", text)  # label matchers
    text = re.sub(r"\[[^\]]*\]", "", text)  # range and subquery selectors
    labels: set[str] = set()

    def grouping(m: re.Match[str]) -> str:
        labels.update(x.strip() for x in m.group(2).split(",") if x.strip())
        return " "

    text = _GROUPING.sub(grouping, text)
    names = set()
    for m in re.finditer(r"(?<![\w.$])[A-Za-z_:][A-Za-z0-9_:]*", text):
        if text[m.end() :].lstrip().startswith("("):
            continue  # a function or an aggregation
        if m.group(0) not in _KEYWORDS:
            names.add(m.group(0))
    return names, labels


def matcher_labels(expr: str) -> set[str]:
    """Label names used in the ``{...}`` matchers of an expression."""
    out: set[str] = set()
    for block in re.findall(r"\{([^}]*)\}", re.sub(r'"(?:[^"\\]|\\.)*"', '""', expr)):
        out.update(m.group(1) for m in re.finditer(r"([A-Za-z_]\w*)\s*(?:=~|!~|!=|=)", block))
    return out


def load_yaml(path: Path) -> Any:
    return yaml.safe_load(path.read_text())


def load_yaml_all(path: Path) -> list[Any]:
    return [d for d in yaml.safe_load_all(path.read_text()) if d is not None]


def dashboard() -> dict[str, Any]:
    data = json.loads(DASHBOARD.read_text())
    assert isinstance(data, dict)
    return data


def dashboard_queries() -> Iterator[tuple[str, str]]:
    """(panel title, PromQL) for every query of the dashboard."""
    for panel in dashboard()["panels"]:
        for target in panel.get("targets", []):
            yield panel["title"], target["expr"]


def grafana_to_promql(expr: str, rate_interval: str = "1m") -> str:
    """A dashboard query as Prometheus itself would receive it from Grafana."""
    out = expr.replace("$__rate_interval", rate_interval)
    return out.replace("$instance", ".*").replace("$vehicle", ".*")


def alert_rules(groups: dict[str, Any] | None = None) -> list[dict[str, Any]]:
    data = groups if groups is not None else load_yaml(ALERTS)
    return [rule for group in data["groups"] for rule in group["rules"]]


def project_version() -> str:
    return str(tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]["version"])


def dependency_spec(name: str) -> str:
    deps = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]["dependencies"]
    for dep in deps:
        m = re.match(r"([A-Za-z0-9_.\-]+)\s*(.*)", dep)
        if m and m.group(1).lower() == name:
            return m.group(2)
    raise KeyError(name)
