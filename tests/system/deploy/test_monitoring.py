"""The Grafana dashboard and the Prometheus alerts ask only for metrics that exist."""

from __future__ import annotations

import json
import re

from posecast.online.metrics import Metrics, SupervisorMetrics
from tests.system.deploy.conftest import ROOT, load_yaml

_SUFFIXES = {"counter": ("_total",), "histogram": ("_bucket", "_sum", "_count"), "gauge": ("",)}


def exported() -> set[str]:
    """Every sample name a node's /metrics can carry (labelled ones before first use too;
    with --workers N, the supervisor's too)."""
    names = set()
    for family in [*Metrics().registry.collect(), *SupervisorMetrics().registry.collect()]:
        for suffix in _SUFFIXES.get(family.type, ("",)):
            names.add(family.name + suffix)
    return names


def referenced(text: str) -> set[str]:
    return set(re.findall(r"\bposecast_[a-z_]+\b", text))


def test_dashboard_panels_query_exported_metrics() -> None:
    dash = json.loads((ROOT / "deploy/grafana/dashboards/posecast.json").read_text("utf-8"))
    exprs = [t["expr"] for p in dash["panels"] for t in p["targets"]]
    assert len(exprs) >= 10 and dash["uid"] == "posecast"
    names = referenced(" ".join(exprs))
    assert names - exported() == set(), names - exported()
    assert {"posecast_bus_connected", "posecast_tick_seconds_bucket"} <= names
    ids = [p["id"] for p in dash["panels"]]
    assert len(ids) == len(set(ids))
    provisioning = load_yaml(ROOT / "deploy/grafana/provisioning/dashboards/posecast.yml")
    assert provisioning["providers"][0]["options"]["path"] == "/var/lib/grafana/dashboards"


def test_alert_rules_use_exported_metrics_and_are_documented() -> None:
    rules = load_yaml(ROOT / "deploy/prometheus/alerts.yml")["groups"][0]["rules"]
    names = referenced(" ".join(r["expr"] for r in rules))
    assert names - exported() == set(), names - exported()
    operations = (ROOT / "docs/operations.md").read_text("utf-8")
    for rule in rules:
        assert rule["alert"] in operations, f"docs/operations.md does not explain {rule['alert']}"
        assert rule["labels"]["severity"] in ("page", "ticket")
    prom = load_yaml(ROOT / "deploy/prometheus/prometheus.yml")
    assert prom["rule_files"] == ["/etc/prometheus/alerts.yml"]


def test_operations_doc_lists_every_metric() -> None:
    operations = (ROOT / "docs/operations.md").read_text("utf-8")
    for family in [*Metrics().registry.collect(), *SupervisorMetrics().registry.collect()]:
        name = family.name + ("_total" if family.type == "counter" else "")
        assert f"`{name}`" in operations, f"docs/operations.md lacks {name}"
