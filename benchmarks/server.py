"""Server benchmark: P simulated players on loopback against a real ``posecast serve``.

    python benchmarks/server.py [--players 64] [--rooms 8] [--samples 100]
                                [--seconds 10] [--procs 2] [--json OUT]

The server runs as a subprocess (``python -m posecast serve``, a
:class:`posecast.testing.serve.ServeProcess`); the clients run in
``--procs`` other processes, each an asyncio loop of WebSocket clients. Every client
sends 60 Hz frames replayed from a generated walk (``walk_clip`` ->
``derive_frames``), on an absolute schedule with a random phase.

Reported (printed, and written with ``--json``):

* end-to-end latency p50/p99: frame sent by player A -> the pose of that seq
  received by ANOTHER client B, minus the look-ahead ``tau / 60`` s that the SSI
  engine holds every pose back with ``--lookahead tau`` (the paper's delayed emission;
  none by default). All processes share CLOCK_MONOTONIC.
* delivery: the share of (frame, room-mate) pairs whose pose arrived (a frame
  superseded before its tick never becomes a pose);
* server CPU share (utime + stime of the server process over the window, in cores)
  and its tick time and overruns from ``/metrics``;
* bandwidth per client, in and out.
"""

from __future__ import annotations

import argparse
import asyncio
import json
import multiprocessing as mp
import os
import random
import time
from pathlib import Path
from typing import Any

import msgpack
import numpy as np

from posecast.testing.serve import Metrics, ServeProcess

SECRET = "bench-secret-" + "x" * 24
FPS = 60.0


def _fixture(seed: int) -> list[list[list[float]]]:
    from posecast.offline.dataset.frames import derive_frames
    from posecast.offline.motion.synthetic import walk_clip

    w = derive_frames(walk_clip(seconds=8.0, fps=FPS, seed=seed))
    rows = np.concatenate([w["tracker_pos"], w["tracker_quat"]], axis=-1).astype(np.float64)
    rows[..., 3:] /= np.linalg.norm(rows[..., 3:], axis=-1, keepdims=True)
    return rows.tolist()  # type: ignore[no-any-return]


async def _client(
    port: int, player: str, room: str, start_at: float, stop_at: float, out: dict[str, Any]
) -> None:
    from websockets.asyncio.client import connect

    from posecast.online.auth.tokens import mint

    frames = _fixture(hash(player) % 16)
    tok = mint(SECRET.encode(), room=room, player=player, ttl_s=3600, now=time.time())
    sent: dict[int, float] = {}
    recv: list[tuple[str, int, float]] = []
    counters = {"bytes_in": 0, "bytes_out": 0}
    async with connect(
        f"ws://127.0.0.1:{port}/", subprotocols=["posecast.v1"], compression=None, max_queue=256
    ) as ws:
        hello = {"type": "hello", "version": 1, "token": tok, "room": room, "name": player}
        await ws.send(msgpack.packb(hello))
        welcome = msgpack.unpackb(await ws.recv())
        assert welcome["type"] == "welcome", welcome

        async def reader() -> None:
            async for data in ws:
                assert isinstance(data, bytes)
                t = time.monotonic()
                counters["bytes_in"] += len(data)
                m = msgpack.unpackb(data)
                if m["type"] == "pose" and m["player"] != player:
                    recv.append((m["player"], m["seq"], t))

        task = asyncio.create_task(reader())
        phase = random.random() / FPS
        seq = 0
        while True:
            due = start_at + phase + seq / FPS
            now = time.monotonic()
            if due > now:
                await asyncio.sleep(due - now)
            if due >= stop_at:
                break
            t = time.monotonic()
            data = msgpack.packb(
                {"type": "frame", "seq": seq, "t": t, "trackers": frames[seq % len(frames)]}
            )
            await ws.send(data)
            counters["bytes_out"] += len(data)
            sent[seq] = t
            seq += 1
        await asyncio.sleep(0.5)  # the last poses are tau ticks behind
        task.cancel()
    out[player] = {"room": room, "sent": sent, "recv": recv, **counters}


def _worker(port: int, clients: list[tuple[str, str]], start_at: float, stop_at: float) -> Any:
    out: dict[str, Any] = {}

    async def main() -> None:
        await asyncio.gather(*(_client(port, p, r, start_at, stop_at, out) for p, r in clients))

    asyncio.run(main())
    return out


def _metric(metrics: Metrics, series: str) -> float:
    return metrics.get(series, float("nan"))


def run(args: argparse.Namespace) -> dict[str, Any]:
    server = ServeProcess(
        "--conn-per-ip-per-min", "100000", "--sockets-per-ip", "100000",
        "--engine-threads", str(args.engine_threads),
        *(["--delayed-emission"] if args.lookahead else []),
        secret=SECRET, samples=args.samples, lookahead=args.lookahead,
    )  # fmt: skip
    try:
        server.wait_ready()
        port = server.port
        players = [(f"p{i}", f"room{i % args.rooms}") for i in range(args.players)]
        chunks = [players[i :: args.procs] for i in range(args.procs)]
        start_at = time.monotonic() + 2.0 + 0.05 * args.players  # all connected by then
        measure_from = start_at + args.warmup
        stop_at = measure_from + args.seconds
        ctx = mp.get_context("spawn")
        with ctx.Pool(args.procs) as pool:
            pending = pool.starmap_async(_worker, [(port, c, start_at, stop_at) for c in chunks])
            time.sleep(max(0.0, measure_from - time.monotonic()))
            cpu0, wall0 = server.cpu_seconds(), time.monotonic()
            time.sleep(max(0.0, stop_at - time.monotonic()))
            cpu1, wall1 = server.cpu_seconds(), time.monotonic()
            results: dict[str, Any] = {}
            for part in pending.get(timeout=args.seconds + args.warmup + 120):
                results.update(part)
        metrics = server.metrics()
    finally:
        server.stop(timeout_s=15)
    return _report(args, results, metrics, (cpu1 - cpu0) / (wall1 - wall0), measure_from, stop_at)


def _report(
    args: argparse.Namespace,
    results: dict[str, Any],
    metrics: Metrics,
    cpu_cores: float,
    t0: float,
    t1: float,
) -> dict[str, Any]:
    tau_s = args.lookahead / FPS
    lat, expected, got = [], 0, 0
    rooms: dict[str, list[str]] = {}
    for p, r in results.items():
        rooms.setdefault(r["room"], []).append(p)
    for r in results.values():
        mates = len(rooms[r["room"]]) - 1
        expected += mates * sum(1 for t in r["sent"].values() if t0 <= t < t1)
    for r in results.values():
        for src, seq, t in r["recv"]:
            ts = results[src]["sent"].get(seq)
            if ts is not None and t0 <= ts < t1:
                lat.append(t - ts - tau_s)
                got += 1
    ms = np.array(lat) * 1000
    span = args.seconds + args.warmup
    tick_n = _metric(metrics, "posecast_tick_seconds_count")
    return {
        "players": args.players,
        "rooms": args.rooms,
        "samples": args.samples,
        "lookahead_frames": args.lookahead,
        "latency_ms_p50": round(float(np.percentile(ms, 50)), 2) if len(ms) else None,
        "latency_ms_p99": round(float(np.percentile(ms, 99)), 2) if len(ms) else None,
        "latency_ms_max": round(float(ms.max()), 2) if len(ms) else None,
        "delivery": round(got / expected, 4) if expected else None,
        "server_cpu_cores": round(cpu_cores, 3),
        "machine_cores": os.cpu_count(),
        "tick_ms_mean": round(1000 * _metric(metrics, "posecast_tick_seconds_sum") / tick_n, 2),
        "tick_overruns": _metric(metrics, "posecast_tick_overruns_total"),
        "ticks": tick_n,
        "frames_superseded": _metric(metrics, 'posecast_frames_dropped_total{reason="superseded"}'),
        "kbit_s_in_per_client": round(
            8 * np.mean([r["bytes_in"] for r in results.values()]) / span / 1000, 1
        ),
        "kbit_s_out_per_client": round(
            8 * np.mean([r["bytes_out"] for r in results.values()]) / span / 1000, 1
        ),
    }


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--players", type=int, default=64)
    ap.add_argument("--rooms", type=int, default=8)
    ap.add_argument("--samples", type=int, default=100, help="latent samples N per player")
    ap.add_argument(
        "--lookahead",
        type=int,
        default=0,
        help="tau, frames: with tau > 0 the server runs the paper's delayed emission "
        "(--delayed-emission), poses tau ticks late, subtracted from the latency (0: the "
        "served default, every pose at its own frame's tick)",
    )
    ap.add_argument("--engine-threads", type=int, default=1)
    ap.add_argument("--seconds", type=float, default=10.0, help="measured window")
    ap.add_argument("--warmup", type=float, default=3.0)
    ap.add_argument("--procs", type=int, default=2, help="client processes")
    ap.add_argument("--json", type=Path)
    args = ap.parse_args(argv)
    report = run(args)
    for key, value in report.items():
        print(f"{key:>24s}: {value}")
    budget = 25.0
    p99 = report["latency_ms_p99"]
    verdict = "met" if p99 is not None and p99 < budget else "NOT met"
    print(f"target p99 < {budget} ms (+ tau): {verdict}")
    if args.json is not None:
        args.json.write_text(json.dumps(report, indent=1) + "\n", encoding="utf-8")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
