"""``posecast-sim``: P simulated headsets streaming to a posecast server.

Each headset replays a BVH file (``--bvh``, several files are dealt out in turn) or
the built-in procedural walk (a different seed per player), optionally with noise
and tracker dropouts, joins its room (players are dealt round-robin over
``--rooms`` rooms) and receives the room's poses. At the end it prints a summary:
frames sent, poses received per second, and the end-to-end latency from sending a
frame to receiving the pose made from it (``pose.seq`` echoes the frame's seq; this
includes the server's look-ahead), p50 and p99.

Examples::

    posecast-sim --secret $SECRET --players 4 --rooms 2 --duration 10
    posecast-sim --secret $SECRET --bvh 05_02.bvh --noise-m 0.002 --dropout 0.02 --json out.json
"""

from __future__ import annotations

import argparse
import asyncio
import json
import sys
import time
from collections.abc import AsyncIterator, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from posecast_client.cli.common import (
    add_server_arguments,
    connect_patiently,
    resolve_server,
    stop_on_signals,
    token_for,
    unique_suffix,
)
from posecast_client.protocol import Error, Pose
from posecast_client.session import Reconnecting
from posecast_client.sources import BvhReplaySource, ReplaySource, TrackerSample, WalkSource


@dataclass
class PlayerReport:
    player: str
    room: str
    frames_sent: int = 0
    frames_dropped: int = 0
    poses: int = 0
    poses_from: dict[str, int] = field(default_factory=dict)  # by the pose's player
    latencies_s: list[float] = field(default_factory=list)
    errors: list[str] = field(default_factory=list)
    reconnects: int = 0
    clock_offset_s: float | None = None
    rtt_s: float | None = None
    failure: str | None = None


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="posecast-sim", description=__doc__.splitlines()[0])
    add_server_arguments(p)
    p.add_argument("--players", type=int, default=2, help="simulated headsets (2)")
    p.add_argument("--rooms", type=int, default=1, help="rooms to deal them over (1)")
    p.add_argument("--room-prefix", default="sim", help="rooms are PREFIX-0, PREFIX-1... (sim)")
    p.add_argument("--rate", type=float, default=60.0, help="frames per second per headset (60)")
    p.add_argument("--duration", type=float, default=10.0, help="seconds to stream (10)")
    p.add_argument("--bvh", type=Path, action="append", help="replay this BVH (repeatable)")
    p.add_argument("--noise-m", type=float, default=0.0, help="position noise s.d., metres")
    p.add_argument("--noise-deg", type=float, default=0.0, help="orientation noise s.d., degrees")
    p.add_argument("--dropout", type=float, default=0.0, help="fraction of time a tracker is lost")
    p.add_argument("--seed", type=int, default=0, help="seed of motion, noise and dropouts")
    p.add_argument("--json", type=Path, help="also write the summary here as JSON")
    p.add_argument("-q", "--quiet", action="store_true", help="print only the summary")
    return p


def make_source(args: argparse.Namespace, i: int, slot_in_room: int) -> ReplaySource:
    """Player ``i``'s headset, standing ``slot_in_room`` places along X from the others."""
    options: dict[str, Any] = {
        "rate_hz": args.rate,
        "loop": True,
        "noise_m": args.noise_m,
        "noise_rad": np.deg2rad(args.noise_deg),
        "dropout": args.dropout,
        "seed": args.seed + i,
        "offset_m": ((slot_in_room % 4) * 1.2, 0.0, (slot_in_room // 4) * 1.2),
    }
    if args.bvh:
        return BvhReplaySource(args.bvh[i % len(args.bvh)], **options)
    return WalkSource(seconds=max(10.0, min(args.duration, 60.0)), **options)


async def _for(
    source: ReplaySource, seconds: float, stop: asyncio.Event
) -> AsyncIterator[TrackerSample]:
    end = time.monotonic() + seconds
    async for sample in source:
        if time.monotonic() >= end or stop.is_set():
            return
        yield sample


async def run_player(
    args: argparse.Namespace,
    i: int,
    report: PlayerReport,
    source: ReplaySource,
    stop: asyncio.Event,
) -> None:
    token = token_for(args, report.room, report.player)
    client = await connect_patiently(args.url, token)
    try:
        await client.join(report.room, f"Sim {i}", rate_hz=min(args.rate, 120.0))
        streaming = asyncio.create_task(client.stream(_for(source, args.duration, stop)))
        async for event in client.events(until=streaming):
            if isinstance(event, Pose):
                report.poses += 1
                report.poses_from[event.player] = report.poses_from.get(event.player, 0) + 1
                sent = client.sent_at(event.seq) if event.player == client.player else None
                if sent is not None:
                    report.latencies_s.append(time.monotonic() - sent)
            elif isinstance(event, Error):
                report.errors.append(event.code)
            elif isinstance(event, Reconnecting) and not args.quiet:
                print(f"{report.player}: reconnecting ({event.cause!r})", file=sys.stderr)
        await streaming
    finally:
        report.frames_sent = client.stats.frames_sent
        report.frames_dropped = client.stats.frames_dropped
        report.reconnects = client.stats.reconnects
        report.clock_offset_s, report.rtt_s = client.clock.offset_s, client.clock.rtt_s
        await client.close()


def summarise(
    reports: Sequence[PlayerReport], seconds: float, args: argparse.Namespace
) -> dict[str, Any]:
    lat = np.array([x for r in reports for x in r.latencies_s]) * 1000.0
    offsets = [r.clock_offset_s for r in reports if r.clock_offset_s is not None]
    rtts = [r.rtt_s for r in reports if r.rtt_s is not None]
    poses = sum(r.poses for r in reports)
    frames = sum(r.frames_sent for r in reports)
    return {
        "players": len(reports),
        "rooms": args.rooms,
        "seconds": round(seconds, 3),
        "frames_sent": frames,
        "frames_dropped": sum(r.frames_dropped for r in reports),
        "frames_per_s": round(frames / seconds, 1),
        "poses_received": poses,
        "poses_per_s": round(poses / seconds, 1),
        "latency_ms_p50": round(float(np.percentile(lat, 50)), 2) if lat.size else None,
        "latency_ms_p99": round(float(np.percentile(lat, 99)), 2) if lat.size else None,
        "latency_samples": int(lat.size),
        "clock_offset_ms": round(float(np.median(offsets)) * 1000, 3) if offsets else None,
        "rtt_ms": round(float(np.median(rtts)) * 1000, 3) if rtts else None,
        "reconnects": sum(r.reconnects for r in reports),
        "errors": sum(len(r.errors) for r in reports),
        "failed": {r.player: r.failure for r in reports if r.failure},
        "poses_from": {r.player: dict(sorted(r.poses_from.items())) for r in reports},
    }


def print_summary(s: dict[str, Any]) -> None:
    print(f"posecast-sim: {s['players']} players in {s['rooms']} rooms for {s['seconds']:.1f} s")
    sent, dropped = s["frames_sent"], s["frames_dropped"]
    print(f"  frames sent     {sent:8d}  ({s['frames_per_s']:.1f}/s, {dropped} dropped)")
    print(f"  poses received  {s['poses_received']:8d}  ({s['poses_per_s']:.1f}/s)")
    if s["latency_samples"]:
        print(
            f"  latency         p50 {s['latency_ms_p50']:.1f} ms  p99 {s['latency_ms_p99']:.1f} ms"
            "  (frame sent -> its pose received, look-ahead included)"
        )
    if s["clock_offset_ms"] is not None:
        print(f"  clock offset    {s['clock_offset_ms']:.3f} ms  (rtt {s['rtt_ms']:.3f} ms)")
    print(
        f"  reconnects {s['reconnects']}, errors {s['errors']}, failed players {len(s['failed'])}"
    )
    for player, why in s["failed"].items():
        print(f"    {player}: {why}")


async def run(args: argparse.Namespace) -> dict[str, Any]:
    stop = asyncio.Event()
    stop_on_signals(stop)
    tag = unique_suffix()
    reports, tasks = [], []
    for i in range(args.players):
        room = f"{args.room_prefix}-{i % args.rooms}"
        report = PlayerReport(player=f"sim-{tag}-{i}", room=room)
        source = make_source(args, i, i // args.rooms)
        reports.append(report)
        tasks.append(asyncio.create_task(run_player(args, i, report, source, stop)))
        await asyncio.sleep(0.01)  # stagger the handshakes a little
    start = time.monotonic()
    results = await asyncio.gather(*tasks, return_exceptions=True)
    for report, result in zip(reports, results, strict=True):
        if isinstance(result, BaseException):
            report.failure = repr(result)
    return summarise(reports, max(1e-3, time.monotonic() - start), args)


def main(argv: Sequence[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    resolve_server(args)
    if args.token and args.players > 1:
        raise SystemExit("posecast-sim: one --token is one player; use --secret for several")
    if args.players < 1 or args.rooms < 1 or args.duration <= 0:
        raise SystemExit("posecast-sim: --players, --rooms and --duration must be positive")
    summary = asyncio.run(run(args))
    print_summary(summary)
    if args.json is not None:
        args.json.write_text(json.dumps(summary, indent=1) + "\n", encoding="utf-8")
    return 1 if summary["failed"] else 0


if __name__ == "__main__":  # pragma: no cover
    raise SystemExit(main())
