"""Connection churn against a real server: what the fatal-error budget buys.

Three processes, as in ``tests/system/reliability/test_hostile_churn.py``: ``posecast serve``
(:class:`posecast.testing.serve.ServeProcess`), the healthy players
(``tests/system/reliability/healthy_players.py``: two rooms of two, 60 Hz) and the churner
(``tests/system/reliability/flooder.py --kind churn``: join, garbage, cut off,
reconnect at once, from ``--ips`` loopback addresses, at niceness 10). For each
configuration, in one run, side by side: a baseline window, then a window under
churn; it prints the healthy players' pose rates (their own process), the server's
ticks and poses per second and its CPU (from ``/proc``), and what the churner got.

    python benchmarks/churn.py                 # budget on (the default 20/min) vs off
    python benchmarks/churn.py --seconds 10 --ips 16
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

from posecast.online.auth.tokens import mint
from posecast.testing.serve import ServeProcess, metric_sum
from posecast.tracking.layouts import Layout

REPO = Path(__file__).resolve().parents[1]
SECRET = "test-secret-" + "x" * 20  # the healthy players' tokens: tests/online/conftest.py


def _players(port: int) -> subprocess.Popen[str]:
    proc = subprocess.Popen(
        [sys.executable, "-m", "tests.system.reliability.healthy_players", str(port)],
        cwd=REPO, stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True,
    )  # fmt: skip
    assert proc.stdout is not None
    line = proc.stdout.readline()
    if json.loads(line or "{}").get("ready") is not True:
        raise RuntimeError(f"healthy players did not start: {line!r}")
    return proc


def _snapshot(server: ServeProcess, players: subprocess.Popen[str]) -> dict[str, Any]:
    assert players.stdin is not None and players.stdout is not None
    m = server.metrics()
    players.stdin.write("report\n")
    players.stdin.flush()
    rep = json.loads(players.stdout.readline())
    return {
        "t": rep["t"],
        "counts": rep["counts"],
        "cpu": server.cpu_seconds(),
        "ticks": m["posecast_ticks_total"],
        "poses": m["posecast_poses_total"],
        "turned_away": metric_sum(m, "posecast_connects_total", result="fatal_budget"),
        "accepted": metric_sum(m, "posecast_connects_total", result="accepted"),
    }


def _window(a: dict[str, Any], b: dict[str, Any]) -> dict[str, Any]:
    dt = b["t"] - a["t"]
    rates = {k: (b["counts"][k] - a["counts"][k]) / dt for k in a["counts"]}
    return {
        "seconds": round(dt, 2),
        "healthy_hz_min": round(min(rates.values()), 1),
        "server_ticks_hz": round((b["ticks"] - a["ticks"]) / dt, 1),
        "server_poses_hz": round((b["poses"] - a["poses"]) / dt, 1),
        "server_cores": round((b["cpu"] - a["cpu"]) / dt, 3),
        "accepted": int(b["accepted"] - a["accepted"]),
        "turned_away": int(b["turned_away"] - a["turned_away"]),
    }


def run(fatal_per_min: int, seconds: float, ips: int, attempts: int) -> dict[str, Any]:
    flags = ["--conn-per-ip-per-min", "1000000", "--fatal-per-ip-per-min", str(fatal_per_min)]
    env = {"POSECAST_LAYOUTS": Layout.HMD3_WAIST.value}
    with ServeProcess(*flags, secret=SECRET, samples=8, lookahead=1, env=env) as server:
        server.wait_ready()
        players = _players(server.port)
        try:
            time.sleep(1.0)
            s0 = _snapshot(server, players)
            time.sleep(seconds)
            s1 = _snapshot(server, players)
            tok = mint(SECRET.encode(), room="r1", player="churn", role="player", ttl_s=600,
                       now=time.time())  # fmt: skip
            churner = subprocess.Popen(
                [sys.executable, "-m", "tests.system.reliability.flooder",
                 "--port", str(server.port), "--token", tok, "--kind", "churn",
                 "--seconds", str(seconds), "--ips", str(ips), "--attempts", str(attempts)],
                cwd=REPO, stdout=subprocess.PIPE, text=True,
                preexec_fn=lambda: os.nice(10),
            )  # fmt: skip
            out, _ = churner.communicate(timeout=seconds + 120)
            s2 = _snapshot(server, players)
        finally:
            if players.stdin is not None:
                players.stdin.close()
            players.wait(timeout=10)
    report = json.loads(out)
    base, during = _window(s0, s1), _window(s1, s2)
    extra_cpu_ms = 1000 * (during["server_cores"] - base["server_cores"]) * during["seconds"]
    return {
        "fatal_per_ip_per_min": fatal_per_min,
        "churner": {
            "attempts": report["attempts"],
            "attempts_per_s": round(report["attempts"] / report["seconds"], 1),
            "outcome": report["outcome"],
        },
        "baseline": base,
        "churn": during,
        "healthy_ratio": round(during["healthy_hz_min"] / base["healthy_hz_min"], 3),
        "server_ms_per_attempt": round(extra_cpu_ms / max(1, report["attempts"]), 3),
    }


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--seconds", type=float, default=8.0, help="each window (default 8)")
    p.add_argument("--ips", type=int, default=8, help="churner addresses (default 8)")
    p.add_argument("--attempts", type=int, default=10**6, help="per address (default: no cap)")
    p.add_argument("--json", type=Path, default=None, help="also write the results here")
    args = p.parse_args()
    results = [run(n, args.seconds, args.ips, args.attempts) for n in (20, 10**6)]
    for r in results:
        label = "budget 20/min" if r["fatal_per_ip_per_min"] == 20 else "budget off"
        b, c = r["baseline"], r["churn"]
        print(
            f"{label:>14}: churner {r['churner']['attempts_per_s']}/s {r['churner']['outcome']}; "
            f"healthy {b['healthy_hz_min']} -> {c['healthy_hz_min']} Hz "
            f"(x{r['healthy_ratio']}); server ticks {b['server_ticks_hz']} -> "
            f"{c['server_ticks_hz']}/s, poses {b['server_poses_hz']} -> {c['server_poses_hz']}/s, "
            f"CPU {b['server_cores']} -> {c['server_cores']} cores "
            f"({r['server_ms_per_attempt']} ms per attempt); accepted {c['accepted']}, "
            f"turned away {c['turned_away']}"
        )
    if args.json is not None:
        args.json.write_text(json.dumps(results, indent=2) + "\n")


if __name__ == "__main__":
    main()
