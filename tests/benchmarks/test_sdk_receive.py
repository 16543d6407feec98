"""``benchmarks/sdk_receive.py`` runs both SDKs on the same messages and prints a row
per step (a few ticks: its figures are the benchmark's to measure, not this test's)."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
SCRIPT = ROOT / "benchmarks" / "sdk_receive.py"


def test_each_step_gets_its_row_for_both_revisions(tmp_path: Path) -> None:
    if not (ROOT / ".git").exists():
        pytest.skip("not a git checkout: no revision to compare with")
    out = subprocess.run(
        [sys.executable, str(SCRIPT), "--ref", "HEAD", "--players", "3", "--ticks", "60",
         "--rounds", "1", "--json", str(tmp_path / "r.json")],
        capture_output=True, text=True, timeout=300,
    )  # fmt: skip
    assert out.returncode == 0, out.stderr
    rows = {ln.split(" (")[0].split()[0]: ln.split() for ln in out.stdout.splitlines()[2:]}
    assert {"decode", "feed", "sample", "frame"} <= set(rows)
    report = json.loads((tmp_path / "r.json").read_text())
    assert set(report["us"]) == {"HEAD", "this tree"}
    assert all(v > 0 for sdk in report["us"].values() for v in sdk.values())
