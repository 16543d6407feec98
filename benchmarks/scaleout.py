"""Scale-out benchmark: what the Redis bus costs, on loopback.

    python benchmarks/scaleout.py [--rooms 8] [--per-room 8] [--samples 8]
                                  [--seconds 10] [--procs 2] [--json OUT]

Starts a ``redis-server`` (Debian's package; a free port, a temporary directory) and
two ``posecast serve --redis`` nodes (:class:`posecast.testing.serve.ServeProcess`).
Every room gets half its players on node A and half on node B, each sending 60 Hz
frames (the client of ``benchmarks/server.py``). Every pose a client receives is
classed **same-node** (its source player is on the receiver's node) or **cross-node**
(it came over Redis), so both latencies come from the same run, the same rooms and
the same ticks; their difference is the bus's cost.

Latency is frame sent -> that seq's pose received by a room-mate, minus the SSI
look-ahead tau / 60 s with ``--lookahead tau`` (the paper's delayed emission; 0 by
default, every pose at its own frame's tick; all processes share CLOCK_MONOTONIC).
Redis load comes from ``INFO stats`` / ``INFO commandstats`` over the measured
window: commands, PUBLISH calls and network bytes per second, plus the nodes' own
``posecast_bus_*`` counters.
"""

from __future__ import annotations

import argparse
import importlib.util
import json
import multiprocessing as mp
import os
import shutil
import socket
import subprocess
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np

from posecast.testing.serve import Metrics, ServeProcess, metric_sum

SECRET = "bench-secret-" + "x" * 24  # benchmarks/server.py's clients mint with this
_SERVER_BENCH = Path(__file__).with_name("server.py")  # its 60 Hz client is reused
_spec = importlib.util.spec_from_file_location("bench_server", _SERVER_BENCH)
assert _spec is not None and _spec.loader is not None
bench_server = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(bench_server)


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def start_redis(workdir: str) -> tuple[subprocess.Popen[bytes], int]:
    binary = shutil.which("redis-server")
    if binary is None:
        raise SystemExit("redis-server not found: apt-get install -y redis-server")
    port = free_port()
    cmd = [binary, "--port", str(port), "--bind", "127.0.0.1", "--dir", workdir,
           "--save", "", "--appendonly", "no", "--loglevel", "warning"]  # fmt: skip
    proc = subprocess.Popen(cmd, stdout=subprocess.DEVNULL)
    for _ in range(200):
        try:
            socket.create_connection(("127.0.0.1", port), timeout=0.2).close()
            return proc, port
        except OSError:
            time.sleep(0.05)
    raise SystemExit("redis-server did not start")


def start_node(name: str, redis_url: str, args: argparse.Namespace) -> ServeProcess:
    return ServeProcess(
        "--node-id", name, "--redis", redis_url, "--conn-per-ip-per-min", "100000",
        "--sockets-per-ip", "100000",
        *(["--delayed-emission"] if args.lookahead else []),
        secret=SECRET, samples=args.samples, lookahead=args.lookahead,
    )  # fmt: skip


def _worker(clients: list[tuple[int, str, str]], start_at: float, stop_at: float) -> Any:
    import asyncio

    out: dict[str, Any] = {}

    async def main() -> None:
        await asyncio.gather(
            *(bench_server._client(port, p, r, start_at, stop_at, out) for port, p, r in clients)
        )

    asyncio.run(main())
    return out


def redis_info(port: int) -> dict[str, float]:
    import redis

    r = redis.Redis(port=port)
    stats, cmds, cpu = r.info("stats"), r.info("commandstats"), r.info("cpu")
    r.close()
    return {
        "cpu_s": float(cpu["used_cpu_sys"]) + float(cpu["used_cpu_user"]),
        "commands": float(stats["total_commands_processed"]),
        "net_in": float(stats["total_net_input_bytes"]),
        "net_out": float(stats["total_net_output_bytes"]),
        "publish": float(cmds.get("cmdstat_publish", {}).get("calls", 0)),
    }


def run(args: argparse.Namespace) -> dict[str, Any]:
    workdir = tempfile.mkdtemp(prefix="posecast-bench-redis-")
    redis_proc, redis_port = start_redis(workdir)
    url = f"redis://127.0.0.1:{redis_port}/0"
    nodes: list[ServeProcess] = []
    try:
        for name in ("node-a", "node-b"):
            nodes.append(start_node(name, url, args))
        for n in nodes:
            n.wait_ready()
        ports = [n.port for n in nodes]
        players = []  # (port, player, room): half of each room on each node
        for r in range(args.rooms):
            for i in range(args.per_room):
                players.append((ports[i % 2], f"r{r}p{i}", f"room{r}"))
        node_of = {p: port for port, p, _ in players}
        chunks = [players[i :: args.procs] for i in range(args.procs)]
        start_at = time.monotonic() + 3.0 + 0.05 * len(players)
        measure_from = start_at + args.warmup
        stop_at = measure_from + args.seconds
        with mp.get_context("spawn").Pool(args.procs) as pool:
            pending = pool.starmap_async(_worker, [(c, start_at, stop_at) for c in chunks])
            time.sleep(max(0.0, measure_from - time.monotonic()))
            info0, t0 = redis_info(redis_port), time.monotonic()
            time.sleep(max(0.0, stop_at - time.monotonic()))
            info1, t1 = redis_info(redis_port), time.monotonic()
            results: dict[str, Any] = {}
            for part in pending.get(timeout=args.seconds + args.warmup + 120):
                results.update(part)
        metrics = [n.metrics() for n in nodes]
    finally:
        for n in nodes:
            n.stop(timeout_s=30)
        redis_proc.terminate()
        redis_proc.wait(timeout=10)
        shutil.rmtree(workdir, ignore_errors=True)
    return report(args, results, node_of, info0, info1, t1 - t0, metrics, measure_from, stop_at)


def report(
    args: argparse.Namespace,
    results: dict[str, Any],
    node_of: dict[str, int],
    info0: dict[str, float],
    info1: dict[str, float],
    span: float,
    metrics: list[Metrics],
    t0: float,
    t1: float,
) -> dict[str, Any]:
    tau_s = args.lookahead / 60.0
    lat: dict[str, list[float]] = {"same": [], "cross": []}
    arrivals: dict[tuple[str, int], dict[str, list[float]]] = {}
    for me, r in results.items():
        for src, seq, t in r["recv"]:
            ts = results[src]["sent"].get(seq)
            if ts is not None and t0 <= ts < t1:
                kind = "same" if node_of[src] == node_of[me] else "cross"
                lat[kind].append((t - ts - tau_s) * 1000)
                arrivals.setdefault((src, seq), {"same": [], "cross": []})[kind].append(t)
    # Paired: the same pose (one source frame, one tick) reaching room-mates on its own
    # node and on the other node; the difference is the bus hop, free of the tick phase
    # and engine time that dominate the absolute latencies.
    paired = [
        1000 * (float(np.median(a["cross"])) - float(np.median(a["same"])))
        for a in arrivals.values()
        if a["same"] and a["cross"]
    ]
    out: dict[str, Any] = {"players": len(results), "rooms": args.rooms, "samples": args.samples}
    for kind, values in lat.items():
        ms = np.array(values)
        out[f"{kind}_node_poses"] = len(ms)
        for q in (50, 99):
            out[f"{kind}_node_p{q}_ms"] = round(float(np.percentile(ms, q)), 2) if len(ms) else None
    for q in (50, 99):
        same, cross = out[f"same_node_p{q}_ms"], out[f"cross_node_p{q}_ms"]
        if same is not None and cross is not None:
            out[f"overhead_p{q}_ms"] = round(cross - same, 2)
    if paired:
        out["paired_poses"] = len(paired)
        for q in (50, 99):
            out[f"paired_extra_p{q}_ms"] = round(float(np.percentile(paired, q)), 2)
    rate = {k: (info1[k] - info0[k]) / span for k in info0}
    out["redis_commands_per_s"] = round(rate["commands"])
    out["redis_publish_per_s"] = round(rate["publish"])
    out["redis_in_kbyte_per_s"] = round(rate["net_in"] / 1000, 1)
    out["redis_out_kbyte_per_s"] = round(rate["net_out"] / 1000, 1)
    out["redis_cpu_share"] = round(rate["cpu_s"], 4)  # of one core (Redis is one thread)
    if rate["publish"]:
        out["redis_cpu_us_per_publish"] = round(1e6 * rate["cpu_s"] / rate["publish"], 2)
        out["publish_bytes_mean"] = round(rate["net_in"] / rate["commands"])
    window = args.seconds + args.warmup + 3.0  # counters span the whole run
    out["bus_out_msgs_per_s_per_node"] = round(
        np.mean([metric_sum(m, "posecast_bus_messages_total", direction="out") for m in metrics])
        / window
    )
    rt_sum = sum(metric_sum(m, "posecast_bus_roundtrip_seconds_sum") for m in metrics)
    rt_n = sum(metric_sum(m, "posecast_bus_roundtrip_seconds_count") for m in metrics)
    out["redis_roundtrip_ms_mean"] = round(1000 * rt_sum / rt_n, 3) if rt_n else None
    out["tick_overruns"] = sum(metric_sum(m, "posecast_tick_overruns_total") for m in metrics)
    out["machine_cores"] = os.cpu_count()
    out["loadavg_1m_at_end"] = round(os.getloadavg()[0], 2)  # the run's own load included
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--rooms", type=int, default=8)
    ap.add_argument("--per-room", type=int, default=8, help="players per room (half per node)")
    ap.add_argument("--samples", type=int, default=8, help="latent samples N (engine cost)")
    ap.add_argument(
        "--lookahead",
        type=int,
        default=0,
        help="tau, frames: with tau > 0 the server runs the paper's delayed emission "
        "(--delayed-emission), poses tau ticks late, subtracted from the latency (0: the "
        "served default, every pose at its own frame's tick)",
    )
    ap.add_argument("--seconds", type=float, default=10.0, help="measured window")
    ap.add_argument("--warmup", type=float, default=3.0)
    ap.add_argument("--procs", type=int, default=2, help="client processes")
    ap.add_argument("--json", type=Path)
    args = ap.parse_args(argv)
    result = run(args)
    for key, value in result.items():
        print(f"{key:>30s}: {value}")
    if args.json is not None:
        args.json.write_text(json.dumps(result, indent=1) + "\n", encoding="utf-8")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
