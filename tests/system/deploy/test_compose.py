"""docker-compose.yml: the Compose schema, ``docker compose config`` where it exists,
and the stack's wiring (two nodes on one Redis behind a WebSocket balancer, scraped).

``compose-spec.json`` beside this file is the Compose Specification's JSON schema as
shipped in compose-go v2.9.1 (Apache-2.0), the library ``docker compose`` loads files
with; it is vendored because no engine or network is available where these run.
"""

from __future__ import annotations

import json
import os
import re
import shutil
import subprocess
from pathlib import Path
from typing import Any

import jsonschema
import pytest

from posecast.online.auth.keys import generate
from posecast.online.config import ServerConfig
from posecast.online.config_cli import option_help
from tests.system.deploy.conftest import ROOT, compose, interpolate, load_yaml

OPTIONS = {env for _, env, _, _ in option_help()}


def _docker_compose() -> list[str] | None:
    """``docker compose`` (the CLI plugin) or ``docker-compose``, if either runs."""
    for cmd in (["docker", "compose"], ["docker-compose"]):
        if shutil.which(cmd[0]) is None:
            continue
        probe = subprocess.run([*cmd, "version"], capture_output=True, text=True, timeout=30)
        if probe.returncode == 0:
            return cmd
    return None


def test_docker_compose_config_accepts_the_file() -> None:
    cmd = _docker_compose()
    if cmd is None:
        pytest.skip(
            "`docker compose` is not installed (the docker client here lacks the compose "
            "plugin); test_compose_file_matches_the_compose_spec_schema checks the schema"
        )
    env = {**os.environ, "POSECAST_TOKEN_SECRET": ""}  # the file's default must do
    out = subprocess.run(
        [*cmd, "-f", str(ROOT / "docker-compose.yml"), "config", "--format", "json"],
        capture_output=True,
        text=True,
        timeout=60,
        env=env,
        cwd=ROOT,
    )
    assert out.returncode == 0, out.stderr
    resolved = json.loads(out.stdout)
    assert {"node-a", "node-b", "redis", "lb", "prometheus", "grafana"} <= set(resolved["services"])


def test_compose_file_matches_the_compose_spec_schema() -> None:
    schema = json.loads((Path(__file__).with_name("compose-spec.json")).read_text("utf-8"))
    validator = jsonschema.Draft7Validator(schema)  # its $schema: draft-07
    errors = [
        f"{'/'.join(map(str, e.absolute_path))}: {e.message}"
        for e in validator.iter_errors(compose())
    ]
    assert not errors, errors
    bad = {**compose(), "services": {"x": {"image": "a", "bogus": 1}}}
    assert list(validator.iter_errors(bad)), "the schema rejects unknown keys"


def _node_env(service: dict[str, Any]) -> dict[str, str]:
    env = service["environment"]
    assert isinstance(env, dict), "environment as a mapping"
    return {k: interpolate(str(v), {}) for k, v in env.items()}


def test_two_nodes_share_redis_and_secret_and_differ_in_node_id() -> None:
    services = compose()["services"]
    nodes = {n: s for n, s in services.items() if s.get("image", "").startswith("posecast")}
    assert set(nodes) == {"node-a", "node-b"}
    envs = {n: _node_env(s) for n, s in nodes.items()}
    for name, env in envs.items():
        assert set(env) <= OPTIONS, f"{name}: unknown POSECAST_* {set(env) - OPTIONS}"
        assert env["POSECAST_REDIS_URL"] == "redis://redis:6379/0"
        assert len(env["POSECAST_TOKEN_SECRET"]) >= 32, "the default secret must be accepted"
        assert env["POSECAST_TOKEN_KEYS"] == "", "a key set is passed through, none by default"
        ServerConfig.from_sources(env)  # the defaults start a node
        assert env["POSECAST_NODE_ID"] == name
        assert nodes[name]["build"] == "." and "command" not in nodes[name]
        assert nodes[name]["depends_on"]["redis"]["condition"] == "service_healthy"
        grace = float(nodes[name]["stop_grace_period"].rstrip("s"))
        assert grace > float(env["POSECAST_DRAIN_TIMEOUT_S"]) + 4, "longer than the drain"
    a, b = envs["node-a"], envs["node-b"]
    assert a["POSECAST_TOKEN_SECRET"] == b["POSECAST_TOKEN_SECRET"], "tokens work on any node"
    assert a["POSECAST_TOKEN_KEYS"] == b["POSECAST_TOKEN_KEYS"]
    keys = {"keys": [generate("EdDSA", "k1")[1]]}  # what compose passes in is taken
    given = {k: interpolate(str(v), {"POSECAST_TOKEN_KEYS": json.dumps(keys)})
             for k, v in nodes["node-a"]["environment"].items()}  # fmt: skip
    assert len(ServerConfig.from_sources(given).key_set()) == 2
    assert services["redis"]["image"].startswith("redis:")


def test_balancer_proxies_websockets_to_every_node_and_the_viewer() -> None:
    services = compose()["services"]
    lb = services["lb"]
    assert lb["image"].startswith("nginx") and "8765:8765" in lb["ports"]
    mount = next(v for v in lb["volumes"] if v.endswith("/etc/nginx/nginx.conf:ro"))
    conf = (ROOT / mount.split(":")[0]).read_text("utf-8")
    upstream = re.search(r"upstream posecast \{(.*?)\}", conf, re.S)
    assert upstream is not None
    assert set(re.findall(r"server ([\w-]+):8765", upstream.group(1))) == {"node-a", "node-b"}
    for location in ("location / {", "location /viewer {"):
        block = conf.split(location, 1)[1].split("}", 1)[0]
        assert "proxy_pass http://posecast;" in block
        assert "proxy_http_version 1.1;" in block
        assert "proxy_set_header Upgrade $http_upgrade;" in block
        assert "proxy_set_header Connection $connection_upgrade;" in block
    assert conf.count("{") == conf.count("}")


def test_prometheus_scrapes_every_node_and_grafana_gets_the_dashboard() -> None:
    services = compose()["services"]
    prom = load_yaml(ROOT / "deploy/prometheus/prometheus.yml")
    (job,) = prom["scrape_configs"]
    targets = {t for sc in job["static_configs"] for t in sc["targets"]}
    assert targets == {"node-a:8765", "node-b:8765"} and job["metrics_path"] == "/metrics"
    assert any(v.startswith("./deploy/prometheus:") for v in services["prometheus"]["volumes"])
    grafana = services["grafana"]["volumes"]
    assert "./deploy/grafana/dashboards:/var/lib/grafana/dashboards:ro" in grafana
    for path in grafana + services["prometheus"]["volumes"] + services["lb"]["volumes"]:
        assert (ROOT / path.split(":")[0]).exists(), path
