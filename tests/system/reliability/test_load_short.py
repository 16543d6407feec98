"""The load suite's CI subset: a 20-second soak of ``benchmarks/load.py`` with churn.

A real ``posecast serve`` (N=10) and two ``posecast-sim`` processes: six players in
rooms of three, one of them leaving and a new one joining every second. The long
run (64 players, ten minutes) is a command in benchmarks/README.md; this one checks
the same invariants at small scale, where a leak per connection still shows: the
server's file descriptors and asyncio tasks follow the churn and come back to their
idle values, every disconnect is one the churn schedule asked for, poses flow in
every window, and the server is alive at the end. Tick times are printed, not
checked: a CI machine is too noisy for a deadline.
"""

from __future__ import annotations

import json
import subprocess
import sys
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[3]
LOAD = REPO / "benchmarks" / "load.py"


def test_short_soak_with_churn_keeps_the_invariants(tmp_path: Path) -> None:
    out = tmp_path / "soak.json"
    t0 = time.monotonic()
    done = subprocess.run(
        [sys.executable, str(LOAD), "soak", "--samples", "10", "--players", "6",
         "--room-size", "3", "--seconds", "20", "--warmup", "5", "--window", "5",
         "--sample-every", "1", "--churn-every", "1", "--max-rss-growth", "10",
         "--json", str(out)],
        capture_output=True, text=True, timeout=120,
    )  # fmt: skip
    wall_s = time.monotonic() - t0
    log = done.stdout + done.stderr
    assert out.exists(), log
    r = json.loads(out.read_text())
    assert r["server_alive"], log
    # Churn happened: about one leave a second, each making room for a new player.
    assert r["churn_leaves"] >= 12, log
    assert r["sessions"] >= 6 + r["churn_leaves"] - 2, log
    # Every disconnect is explained: the server accepted one connection per session.
    assert r["connection_losses"] == 0 and r["failed_players"] == {}, log
    assert r["error_messages"] == 0 and r["unexplained_disconnects"] == 0, log
    assert r["server_accepted_connections"] == r["sessions"], log
    # No FD or task growth beyond what the connections in transition explain...
    lo, hi = r["fds_under_load_min_max"]
    assert hi - lo <= 4, log
    lo, hi = r["tasks_under_load_min_max"]
    assert hi - lo <= 8, log
    # ...and back to idle once the clients are gone.
    assert r["fds_idle_after"] <= r["fds_idle_before"], log
    assert r["tasks_idle_after"] <= r["tasks_idle_before"], log
    # Poses flowed in every window.
    assert len(r["windows"]) == 4, log
    assert all(w["poses_received_per_s"] > 0 for w in r["windows"]), log
    assert r["delivery_worst_window"] >= 0.5, log
    assert r["ok"] and done.returncode == 0, log
    assert wall_s < 60, wall_s
