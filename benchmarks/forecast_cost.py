"""What the forecast (``hello.forecast_ms``, docs/latency.md) costs the server per tick,
and that it costs nothing when nobody asks (no sockets, simulated time).

    python benchmarks/forecast_cost.py --players 8,32 --ticks 300 --samples 100

One room of ``P`` players streams the SDK's procedural walk (a seed each) through the
server's own pure core: a ``Hub`` and the engine thread's ``EngineWorker`` on the
shipped models. Three settings, run one after the other on the same players: no
spectator asks for a forecast (``off``), one v2 spectator asks for 67 ms (``one``),
and two ask for 33 and 67 ms (``two``). Per tick: the worker's step (engine,
quantising, the forecasts) and the hub's ``deliver`` plus every client's outbox
``take`` (routing, v2 records), wall milliseconds, p50 and mean after a warm-up.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np
from posecast_client.sources import WalkSource

from posecast.online.auth.tokens import mint
from posecast.online.config import ServerConfig
from posecast.online.core.hub import Hub
from posecast.online.engine.config import EngineConfig
from posecast.online.inference.loader import load_multi_engine
from posecast.online.metrics import Metrics
from posecast.online.protocol import encode
from posecast.online.protocol.messages import Frame, Hello
from posecast.online.shell.ticker import EngineWorker

SECRET = "forecast-bench-" + "x" * 24
SETTINGS = {"off": (), "one": (67.0,), "two": (33.0, 67.0)}


def run(
    engine: Any, players: int, asks: tuple[float, ...], ticks: int, warm: int
) -> dict[str, float]:
    cfg = ServerConfig(token_secret=SECRET, port=0, samples=1, max_watchers_per_room=8,
                       conn_per_ip_per_min=10_000, fatal_per_ip_per_min=10_000,
                       sockets_per_ip=10_000)  # fmt: skip
    now = 1000.0
    hub = Hub(cfg, Metrics(), wall_offset_s=time.time() - now)
    room = f"fc-{players}-{len(asks)}"

    def tok(player: str, role: str = "player") -> str:
        return mint(SECRET.encode(), room=room, player=player, role=role, ttl_s=3600,
                    now=time.time())  # fmt: skip

    conns = []
    for i in range(players):
        c = hub.connect("10.0.0.1", now, 2)
        hub.receive(c, encode(Hello(2, tok(f"p{i}"), room, f"P{i}")), now)
        conns.append(c)
    for k, ms in enumerate(asks):
        c = hub.connect("10.0.0.2", now, 2)
        hub.receive(c, encode(Hello(2, tok(f"w{k}", "spectator"), room, f"W{k}",
                                    forecast_ms=ms)), now)  # fmt: skip
        conns.append(c)
    sources = [WalkSource(seconds=10.0, seed=i, loop=True).samples() for i in range(players)]
    worker = EngineWorker(engine)
    step, route = [], []
    for k in range(warm + ticks):
        now += 1 / 60
        for c, src in zip(conns, sources, strict=False):
            s = next(src)
            hub.receive(c, encode(Frame(k, now, s.positions, s.orientations, s.valid)), now)
        t0 = time.perf_counter()
        out = worker.step(hub.take_tick_input(), now)
        t1 = time.perf_counter()
        hub.deliver(out, now)
        for c in conns:
            hub.outbox(c).take(now)  # type: ignore[union-attr]
        t2 = time.perf_counter()
        if k >= warm:
            step.append(1000 * (t1 - t0))
            route.append(1000 * (t2 - t1))
        if asks and k == warm:
            assert out.ahead, "no forecast made"  # the setting took
    return {
        "step_ms_p50": float(np.median(step)),
        "step_ms_mean": float(np.mean(step)),
        "route_ms_p50": float(np.median(route)),
        "route_ms_mean": float(np.mean(route)),
    }


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--players", default="8,32", help="players per room, comma-separated")
    ap.add_argument("--ticks", type=int, default=300, help="measured ticks per setting")
    ap.add_argument("--samples", type=int, default=100, help="latent samples N")
    ap.add_argument("--json", type=Path, default=None)
    args = ap.parse_args(argv)
    report: dict[str, Any] = {}
    head = ("players", "setting", "step p50", "step mean", "route p50", "route mean")
    print(" ".join(f"{h:>10}" for h in head))
    for p in [int(x) for x in args.players.split(",")]:
        for name, asks in SETTINGS.items():
            engine = load_multi_engine(EngineConfig(samples=args.samples), ["hmd3+waist"])
            r = run(engine, p, asks, args.ticks, warm=30)
            report[f"{p}/{name}"] = r
            figures = " ".join(f"{v:>10.2f}" for v in r.values())
            print(f"{p:>10} {name:>10} {figures}")
    if args.json is not None:
        args.json.write_text(json.dumps(report, indent=1) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
