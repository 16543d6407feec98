"""Helpers for the deployment checks: the repository's files, parsed.

There is no container engine where these tests run, so they check what can be
checked without one: linters and schemas where a registry ships them (hadolint,
the Kubernetes and Compose schemas, kubeconform and ``docker compose`` when on
PATH), structure with small checkers, and the image's command run outside Docker.
The Redis fixtures of ``tests/system/scaleout`` are reused (imported, so pytest sees them).
"""

from __future__ import annotations

import json
import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import yaml

from tests.system.scaleout.conftest import redis_server, redis_server_bin  # noqa: F401 (fixtures)

ROOT = Path(__file__).resolve().parents[3]
K8S = ROOT / "deploy" / "kubernetes"


def load_yaml(path: Path) -> Any:
    return yaml.safe_load(path.read_text("utf-8"))


def k8s_documents() -> list[dict[str, Any]]:
    """Every Kubernetes object under deploy/kubernetes (kustomization.yaml aside)."""
    docs = []
    for path in sorted(K8S.glob("*.yaml")):
        if path.name != "kustomization.yaml":
            docs += [d for d in yaml.safe_load_all(path.read_text("utf-8")) if d]
    return docs


def compose() -> dict[str, Any]:
    data: dict[str, Any] = load_yaml(ROOT / "docker-compose.yml")
    return data


def interpolate(value: str, env: dict[str, str]) -> str:
    """Compose's ``${VAR}`` / ``${VAR:-default}`` / ``${VAR:?error}`` substitution."""

    def one(m: re.Match[str]) -> str:
        name, op, arg = m.group(1), m.group(2) or "", m.group(3) or ""
        if env.get(name):
            return env[name]
        if op == ":?":
            raise AssertionError(f"compose needs ${name}: {arg}")
        return arg

    return re.sub(r"\$\{(\w+)(:-|:\?)?([^}]*)\}", one, value)


@dataclass
class Stage:
    base: str
    name: str
    instructions: list[tuple[str, str]] = field(default_factory=list)

    def all(self, keyword: str) -> list[str]:
        return [args for kw, args in self.instructions if kw == keyword]

    def env(self) -> dict[str, str]:
        out: dict[str, str] = {}
        for args in self.all("ENV"):
            for m in re.finditer(r'(\w+)=("[^"]*"|\S+)', args):
                out[m.group(1)] = m.group(2).strip('"')
        return out

    def exec_form(self, keyword: str) -> list[str]:
        found = self.all(keyword)
        if not found:
            return []
        args = found[-1]
        args = re.sub(r"^(--\S+\s+)*CMD\s+", "", args) if keyword == "HEALTHCHECK" else args
        value = json.loads(args)
        assert isinstance(value, list), f"{keyword} must use the exec (JSON) form"
        return [str(v) for v in value]


def dockerfile_stages(path: Path = ROOT / "Dockerfile") -> list[Stage]:
    """The Dockerfile's stages: continuation lines joined, comments dropped."""
    logical, buf = [], ""
    for line in path.read_text("utf-8").splitlines():
        if not buf and (not line.strip() or line.lstrip().startswith("#")):
            continue
        if line.rstrip().endswith("\\"):
            buf += line.rstrip()[:-1] + " "
            continue
        logical.append((buf + line).strip())
        buf = ""
    stages: list[Stage] = []
    for entry in logical:
        keyword, _, args = entry.partition(" ")
        keyword = keyword.upper()
        if keyword == "FROM":
            parts = args.split()
            name = parts[2] if len(parts) >= 3 and parts[1].upper() == "AS" else ""
            stages.append(Stage(parts[0], name))
        elif stages:
            stages[-1].instructions.append((keyword, args.strip()))
    return stages
