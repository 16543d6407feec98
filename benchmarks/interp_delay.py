"""The adaptive render delay against the fixed 0.1 s: ``python benchmarks/interp_delay.py
[--seconds 60] [--seeds 5] [--json out.json]``.

A simulated link with no sockets, on the Python SDK's ``PoseBuffer``
(``posecast_client.interp``): 60 Hz poses stamped with their tick's server time, each
delivered ``latency + uniform(0, hold)`` later (so poses overtake each other), a share
``drop`` lost; the display clock is the server's. A 90 Hz display samples one buffer
fed every pose that has arrived by its frame, from 0.05 s on. Links:

* ``loopback``: 1 ms latency, 1 ms of jitter (a loopback socket);
* ``relay``: 5 ms latency, 0-40 ms held (the reliability suite's ``LossyRelay``,
  ``jitter_s=0.040``, applied to poses);
* ``lossy_relay``: the relay with 20 % of poses lost (``drop=0.2``);
* ``bursty``: 2 ms latency, but every second the link stalls 0.2 s and then
  delivers what it held at once.

For each link and each buffer (the adaptive default, then ``adaptive=False`` at 0.1 s),
over the frames from ``--settle`` (8 s) on: the median and largest render delay, the
share of frames that interpolate (the rest extrapolate or hold), and, over every
frame, the slowest and fastest rate at which the shown time ran against real time.
Each figure is over all ``--seeds`` runs (the share: pooled; the delays: the median of
the per-run medians, the largest of the maxima).
"""

from __future__ import annotations

import argparse
import json
import statistics
from dataclasses import dataclass
from typing import Any

import numpy as np
from posecast_client.interp import InterpConfig, PoseBuffer
from posecast_client.protocol import Pose

POSE_HZ, DISPLAY_HZ, T0 = 60.0, 90.0, 1000.0
LINKS: dict[str, dict[str, float]] = {
    "loopback": {"latency": 0.001, "hold": 0.001},
    "relay": {"latency": 0.005, "hold": 0.040},
    "lossy_relay": {"latency": 0.005, "hold": 0.040, "drop": 0.2},
    "bursty": {"latency": 0.002, "hold": 0.0, "stall": 0.2},
}
BUFFERS = {"adaptive": InterpConfig(), "fixed_0.1": InterpConfig(adaptive=False, delay_s=0.1)}


def arrivals(
    n: int, seed: int, latency: float, hold: float, drop: float = 0.0, stall: float = 0.0
) -> Any:
    """Arrival time of each of ``n`` 60 Hz poses (``inf``: lost), seeded."""
    rng = np.random.default_rng(seed)
    t = T0 + np.arange(n) / POSE_HZ
    arrive = t + latency + rng.uniform(0.0, hold, size=n)
    if stall > 0.0:  # held from 0.5 s into each second until the stall ends
        sec = np.floor(t - T0)
        held = (t - T0 - sec >= 0.5) & (t - T0 - sec < 0.5 + stall)
        arrive[held] = T0 + sec[held] + 0.5 + stall + latency
    arrive[rng.random(n) < drop] = np.inf
    return arrive


@dataclass
class Run:
    delays: list[float]  # per settled frame
    interpolated: int
    settled: int
    rate_min: float
    rate_max: float


def play(arrive: Any, config: InterpConfig, settle_s: float) -> Run:
    n = len(arrive)
    order = [int(k) for k in np.argsort(arrive, kind="stable") if np.isfinite(arrive[k])]
    buf, nxt = PoseBuffer(config), 0
    delays: list[float] = []
    interpolated = settled = 0
    last: tuple[float, float] | None = None
    rate_min, rate_max = np.inf, -np.inf
    for f in range(int((n / POSE_HZ - 0.1) * DISPLAY_HZ)):
        now = T0 + 0.05 + f / DISPLAY_HZ
        while nxt < len(order) and arrive[order[nxt]] <= now:
            k = order[nxt]
            buf.push(Pose("p", k, T0 + k / POSE_HZ, np.array([[k / POSE_HZ, 1.0, 0.0]])))
            nxt += 1
        shown = buf.pose_at(now)
        if shown is None:
            continue
        if last is not None:
            rate = (shown.t - last[1]) / (now - last[0])
            rate_min, rate_max = min(rate_min, rate), max(rate_max, rate)
        last = (now, shown.t)
        if now >= T0 + settle_s:
            settled += 1
            interpolated += shown.mode == "interpolate"
            delays.append(buf.delay_s)
    return Run(delays, interpolated, settled, float(rate_min), float(rate_max))


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--seconds", type=float, default=60.0, help="stream length per run")
    ap.add_argument("--seeds", type=int, default=5)
    ap.add_argument("--settle", type=float, default=8.0, help="figures from this many s on")
    ap.add_argument("--json", help="also write the figures here")
    args = ap.parse_args(argv)
    n = int(args.seconds * POSE_HZ)
    rows: list[dict[str, Any]] = []
    print(
        "| link | buffer | median delay | largest delay | frames interpolating | shown-time rate |"
    )
    print("|---|---|---:|---:|---:|---|")
    for link, kw in LINKS.items():
        for name, cfg in BUFFERS.items():
            runs = [
                play(arrivals(n, seed, **kw), cfg, args.settle) for seed in range(1, args.seeds + 1)
            ]
            row = {
                "link": link,
                "buffer": name,
                "median_delay_ms": 1e3
                * statistics.median(statistics.median(r.delays) for r in runs),
                "max_delay_ms": 1e3 * max(max(r.delays) for r in runs),
                "interpolated": sum(r.interpolated for r in runs) / sum(r.settled for r in runs),
                "rate_min": min(r.rate_min for r in runs),
                "rate_max": max(r.rate_max for r in runs),
            }
            rows.append(row)
            delay = f"{row['median_delay_ms']:.1f} ms | {row['max_delay_ms']:.1f} ms"
            rate = f"{row['rate_min']:.3f} to {row['rate_max']:.3f}"
            print(f"| {link} | {name} | {delay} | {100 * row['interpolated']:.2f} % | {rate} |")
    if args.json:
        with open(args.json, "w", encoding="utf-8") as f:
            json.dump({"args": vars(args), "rows": rows}, f, indent=1)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
