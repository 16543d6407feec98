"""``benchmarks/decoders.py`` runs and prints one row per engine (a few ticks: its
figures are the benchmark's to measure, not this test's)."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

SCRIPT = Path(__file__).resolve().parents[2] / "benchmarks" / "decoders.py"


def _run(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, str(SCRIPT), *args], capture_output=True, text=True, timeout=300
    )


def test_each_engine_gets_its_row_and_ratio() -> None:
    pytest.importorskip("posecast._native")
    out = _run(
        "--players", "2", "--ticks", "3", "--warmup", "1",
        "shipped", "shipped@generic", "shipped@generic:bf16",
    )  # fmt: skip
    assert out.returncode == 0, out.stderr
    rows = [ln.split() for ln in out.stdout.splitlines() if ln.startswith("shipped")]
    assert [r[0] for r in rows] == ["shipped", "shipped@generic", "shipped@generic:bf16"]
    assert rows[0][-2] == "1.00x" and all(float(r[1]) > 0 for r in rows)
    assert [r[-1] for r in rows[1:]] == ["fp32", "bf16-emulated"]


def test_a_level_the_cpu_cannot_run_is_refused_by_name() -> None:
    pytest.importorskip("posecast._native")
    out = _run("--players", "1", "--ticks", "1", "shipped@avx9")
    assert out.returncode == 2 and "shipped@avx9" in out.stderr and "generic" in out.stderr
    out = _run("--players", "1", "--ticks", "1", "shipped@generic:fp16")
    assert out.returncode == 2 and "shipped@generic:fp16" in out.stderr and "bf16" in out.stderr
