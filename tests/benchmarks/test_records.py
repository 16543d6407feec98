"""``benchmarks/records.py`` runs, prints a row per count of poses with both encoders
and their ratio, and finds that they wrote the same bytes (a few ticks: its timings
are the benchmark's to measure, not this test's)."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

SCRIPT = Path(__file__).resolve().parents[2] / "benchmarks" / "records.py"


def test_each_count_gets_both_encoders_and_the_same_bytes(tmp_path: Path) -> None:
    pytest.importorskip("posecast._native")
    out = subprocess.run(
        [
            sys.executable,
            str(SCRIPT),
            "--poses",
            "1,12",
            "--ticks",
            "4",
            "--json",
            str(tmp_path / "r.json"),
        ],
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert out.returncode == 0, out.stderr
    assert "server: native" in out.stdout
    rows = json.loads((tmp_path / "r.json").read_text())
    assert [r["poses"] for r in rows] == [1, 12]
    for r in rows:
        assert r["numpy_p50_ms"] > 0 and r["native_p50_ms"] > 0
        assert r["ratio_p50"] == pytest.approx(r["numpy_p50_ms"] / r["native_p50_ms"])
        assert r["same_bytes"] == 1.0
