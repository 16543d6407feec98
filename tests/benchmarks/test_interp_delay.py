"""``benchmarks/interp_delay.py`` runs and prints a row per link and buffer: the
adaptive delay settles under the fixed 0.1 s on loopback, the shown time runs within
the 5 % slew, and on the bursty link the adaptive buffer interpolates where the fixed
one cannot (a short run: the figures are the benchmark's, with its defaults)."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

SCRIPT = Path(__file__).resolve().parents[2] / "benchmarks" / "interp_delay.py"


def test_rows_per_link_and_buffer(tmp_path: Path) -> None:
    args = ["--seconds", "12", "--seeds", "1", "--settle", "6", "--json", str(tmp_path / "d.json")]
    out = subprocess.run(
        [sys.executable, str(SCRIPT), *args], capture_output=True, text=True, timeout=300
    )
    assert out.returncode == 0, out.stderr
    rows = {
        (r["link"], r["buffer"]): r for r in json.loads((tmp_path / "d.json").read_text())["rows"]
    }
    assert len(rows) == 8 and out.stdout.count("\n| ") == 8
    assert rows["loopback", "adaptive"]["median_delay_ms"] < 40.0
    assert rows["loopback", "fixed_0.1"]["median_delay_ms"] == 100.0
    for r in rows.values():
        assert 0.95 - 1e-9 <= r["rate_min"] <= r["rate_max"] <= 1.05 + 1e-9
    assert rows["bursty", "adaptive"]["interpolated"] > rows["bursty", "fixed_0.1"]["interpolated"]
