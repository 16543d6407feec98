"""deploy/kubernetes: strict schema validation and the wiring between the objects.

Schemas: the ``kubernetes-validate`` package (in posecast[dev]) ships the Kubernetes
JSON schemas, so no download is needed. It validates every object strictly (unknown
fields are errors). When ``kubeconform`` is on PATH (``go install
github.com/yannh/kubeconform/cmd/kubeconform@latest``) it runs too, on standalone
copies of the same schemas written to a temporary directory.
"""

from __future__ import annotations

import json
import shutil
import subprocess
from pathlib import Path
from typing import Any

import pytest

from posecast.online.config import ServerConfig
from posecast.online.config_cli import option_help
from tests.system.deploy.conftest import K8S, k8s_documents, load_yaml

K8S_VERSION = "1.30.0"
OPTIONS = {env: name for name, env, _, _ in option_help()}


def by_kind(kind: str, name: str | None = None) -> dict[str, Any]:
    found = [
        d
        for d in k8s_documents()
        if d["kind"] == kind and (name is None or d["metadata"]["name"] == name)
    ]
    assert len(found) == 1, (kind, name, len(found))
    return found[0]


def test_every_object_passes_the_strict_kubernetes_schema() -> None:
    kv = pytest.importorskip("kubernetes_validate", reason="pip install kubernetes-validate")
    docs = k8s_documents()
    assert {d["kind"] for d in docs} >= {
        "Deployment", "Service", "ConfigMap", "Secret", "HorizontalPodAutoscaler",
        "PodDisruptionBudget",
    }  # fmt: skip
    for doc in docs:
        kv.validate(doc, K8S_VERSION, strict=True)  # raises ValidationError
    bad = json.loads(json.dumps(by_kind("Deployment", "posecast")))
    bad["spec"]["bogus"] = 1
    with pytest.raises(kv.ValidationError):
        kv.validate(bad, K8S_VERSION, strict=True)


def test_kubeconform_accepts_the_manifests(tmp_path: Path) -> None:
    binary = shutil.which("kubeconform")
    if binary is None:
        pytest.skip("kubeconform is not on PATH; the kubernetes-validate test checks the schemas")
    kv = pytest.importorskip("kubernetes_validate", reason="its schemas feed kubeconform")
    src = Path(kv.__file__).parent / "kubernetes-json-schema" / f"v{K8S_VERSION}-local-strict"
    dst = tmp_path / f"v{K8S_VERSION}-standalone-strict"
    dst.mkdir()
    # kubeconform wants self-contained schemas: inline the shared definitions.
    defs = json.loads(
        (src / "_definitions.json").read_text().replace("/api/_definitions.json#", "#")
    )
    kinds = {"deployment-apps-v1", "service-v1", "configmap-v1", "secret-v1",
             "horizontalpodautoscaler-autoscaling-v2", "poddisruptionbudget-policy-v1"}  # fmt: skip
    for kind in kinds:
        schema = json.loads(
            (src / f"{kind}.json").read_text().replace("/api/_definitions.json#", "#")
        )
        schema["$defs"] = defs["$defs"]
        (dst / f"{kind}.json").write_text(json.dumps(schema))
    template = (
        f"{tmp_path}/{{{{ .NormalizedKubernetesVersion }}}}-standalone{{{{ .StrictSuffix }}}}"
        "/{{ .ResourceKind }}{{ .KindSuffix }}.json"
    )
    out = subprocess.run(
        [binary, "-strict", "-summary", "-kubernetes-version", K8S_VERSION,
         "-schema-location", template, "-skip", "Kustomization", str(K8S)],
        capture_output=True, text=True, timeout=120,
    )  # fmt: skip
    assert out.returncode == 0 and "Invalid: 0, Errors: 0" in out.stdout, out.stdout + out.stderr


def test_kustomization_lists_every_manifest() -> None:
    listed = set(load_yaml(K8S / "kustomization.yaml")["resources"])
    assert listed == {p.name for p in K8S.glob("*.yaml")} - {"kustomization.yaml"}


def test_probes_secret_config_and_selectors_are_wired() -> None:
    dep = by_kind("Deployment", "posecast")
    pod = dep["spec"]["template"]
    labels = pod["metadata"]["labels"]
    assert dep["spec"]["selector"]["matchLabels"] == labels
    (c,) = pod["spec"]["containers"]
    port = {p["name"]: p["containerPort"] for p in c["ports"]}["ws"]
    assert c["livenessProbe"]["httpGet"] == {"path": "/healthz", "port": "ws"}
    assert c["readinessProbe"]["httpGet"] == {"path": "/readyz", "port": "ws"}
    assert c["startupProbe"]["httpGet"]["path"] == "/healthz"

    refs = {k: v["name"] for e in c["envFrom"] for k, v in e.items()}
    config = by_kind("ConfigMap", refs["configMapRef"])["data"]
    # The token key set: a Secret mounted as a directory (so rotations reach the pod),
    # at the file the ConfigMap names, re-read at an interval.
    (mount,) = [m for m in c["volumeMounts"] if m["name"] == "token-keys"]
    (volume,) = [v for v in pod["spec"]["volumes"] if v["name"] == "token-keys"]
    secret = by_kind("Secret", volume["secret"]["secretName"])
    assert "subPath" not in mount and mount["readOnly"] is True
    (name,) = secret["stringData"]
    assert config["POSECAST_TOKEN_KEYS_FILE"] == f"{mount['mountPath']}/{name}"
    assert float(config["POSECAST_TOKEN_KEYS_RELOAD_S"]) > 0
    assert not {"POSECAST_TOKEN_SECRET", "POSECAST_TOKEN_KEYS"} & set(config), "keys: Secret"
    assert set(config) <= set(OPTIONS), f"unknown options {set(config) - set(OPTIONS)}"
    assert int(config["POSECAST_PORT"]) == port
    assert c["env"][0]["name"] == "POSECAST_NODE_ID"  # the pod's name
    # The ConfigMap is a valid configuration once a real secret is supplied.
    values = {OPTIONS[k]: v for k, v in config.items()}
    cfg = ServerConfig.from_sources(_with_keys(config))
    assert cfg.redis_url == values["redis_url"]
    redis_host = cfg.redis_url.split("//")[1].split(":")[0]
    assert by_kind("Service", redis_host)["spec"]["ports"][0]["port"] == 6379

    svc = by_kind("Service", "posecast")
    assert svc["spec"]["selector"] == labels and svc["spec"]["ports"][0]["targetPort"] == "ws"
    assert by_kind("PodDisruptionBudget")["spec"]["selector"]["matchLabels"] == labels
    target = by_kind("HorizontalPodAutoscaler")["spec"]["scaleTargetRef"]
    assert (target["kind"], target["name"]) == ("Deployment", "posecast")
    assert c["resources"]["requests"]["cpu"], "CPU utilisation needs a request"


def test_termination_grace_outlasts_prestop_and_drain() -> None:
    dep = by_kind("Deployment", "posecast")
    spec = dep["spec"]["template"]["spec"]
    (c,) = spec["containers"]
    config = by_kind("ConfigMap", "posecast-config")["data"]
    cfg = ServerConfig.from_sources(_with_keys(config))
    pre_stop = float(c["lifecycle"]["preStop"]["exec"]["command"][-1])
    needed = pre_stop + cfg.drain_timeout_s + cfg.close_timeout_s + cfg.redis_timeout_s
    assert spec["terminationGracePeriodSeconds"] > needed, needed
    assert dep["spec"]["strategy"]["rollingUpdate"]["maxUnavailable"] == 0
    assert spec["securityContext"]["runAsNonRoot"] is True


def _with_keys(config: dict[str, str]) -> dict[str, str]:
    """The ConfigMap's settings with a real key set in place of the mounted file."""
    from posecast.online.auth.keys import generate

    keys = json.dumps({"keys": [generate("ES256", "k")[1]]})
    return {**config, "POSECAST_TOKEN_KEYS_FILE": "", "POSECAST_TOKEN_KEYS": keys}


def test_the_placeholder_secret_is_refused(tmp_path: Path) -> None:
    """Applying secret.yaml unchanged must not give a running cluster with a known key."""
    (text,) = by_kind("Secret", "posecast-token-keys")["stringData"].values()
    from posecast.errors import ConfigError

    (tmp_path / "token-keys.json").write_text(text)
    with pytest.raises(ConfigError, match="at least one key"):
        ServerConfig(token_keys_file=str(tmp_path / "token-keys.json"))
