"""``posecast-sim``: P simulated headsets streaming to a posecast server.

Each headset replays a BVH file (``--bvh``, several files are dealt out in turn) or
the built-in procedural walk (a different seed per player), optionally with noise
and tracker dropouts, joins its room (players are dealt round-robin over
``--rooms`` rooms) and receives the room's poses. At the end it prints a summary:
frames sent, poses received per second, and the end-to-end latency from sending a
frame to receiving the pose made from it (``pose.seq`` echoes the frame's seq; this
includes the server's look-ahead), p50 and p99, and ``bytes_per_pose``: the mean
WebSocket payload bytes per pose received, counting every message that carried
poses (a v1 ``pose`` each, or a v2 ``poses`` per tick), so a v2 message's own
overhead is shared out over the poses in it. ``--protocol 1`` makes the headsets
v1 clients (for comparison), ``--pose-rate`` asks a v2 server for fewer poses.

For load tests (``benchmarks/load.py``): ``--churn-every S`` makes one player leave
every S seconds (it says ``bye``) and a new player, with a fresh id and token, join
its room in its place; the players take turns. A connection lost without being asked
to leave is counted as a loss (``connection_losses``), so churn and unexplained
disconnects are told apart, and ``first_pose_ms`` times each player from connecting
to its own first pose. ``--progress-every S`` prints a ``posecast-sim progress {json}``
line every S seconds while it runs. SIGINT or SIGTERM ends a run early, with its
summary.

Examples::

    posecast-sim --secret $SECRET --players 4 --rooms 2 --duration 10
    posecast-sim --secret $SECRET --bvh 05_02.bvh --noise-m 0.002 --dropout 0.02 --json out.json
    posecast-sim --secret $SECRET --players 64 --rooms 16 --duration 600 --churn-every 3
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import itertools
import json
import math
import sys
import time
from collections.abc import AsyncIterator, Iterator, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from posecast_client.cli.common import (
    Parser,
    add_server_arguments,
    check_room,
    connect_patiently,
    describe,
    print_error,
    resolve_server,
    stop_on_signals,
    token_for,
    unique_suffix,
    usage_error,
)
from posecast_client.errors import BvhError
from posecast_client.protocol import Error, Layout, Pose
from posecast_client.session import Reconnecting
from posecast_client.sites import tracker_set
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
    losses: int = 0  # connections lost while not leaving (each one's first Reconnecting)
    churned: bool = False  # left because the churn schedule asked it to
    active: bool = False  # joined and not yet left
    first_pose_s: float | None = None  # from connecting to receiving its own first pose
    clock_offset_s: float | None = None
    rtt_s: float | None = None
    failure_code: str = "INTERNAL"  # and that failure's code and hint (common.describe)
    failure_hint: str = ""
    failure: str | None = None
    pose_bytes: int = 0  # payload bytes of the messages that carried poses
    version: int = 0  # the protocol the server chose


@dataclass
class Slot:
    """A place in a room that one player holds at a time (another after churn)."""

    index: int
    room: str
    place: int  # the slot's place in its room (sets the avatar's offset)
    leave: asyncio.Event = field(default_factory=asyncio.Event)  # the current player's


P = "posecast-sim"  # the program, as its errors name it
MAX_RATE_HZ = 1000.0  # the most a hello's rate_hz may say (proto/README.md)


def build_parser() -> argparse.ArgumentParser:
    p = Parser(prog=P, description=__doc__.splitlines()[0])
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
    p.add_argument(
        "--churn-every", type=float, default=0.0, metavar="S",
        help="every S seconds one player leaves and a new one takes its place (0: never)",
    )  # fmt: skip
    p.add_argument(
        "--progress-every", type=float, default=0.0, metavar="S",
        help="print a 'posecast-sim progress {json}' line every S seconds (0: never)",
    )  # fmt: skip
    p.add_argument(
        "--protocol",
        type=int,
        choices=(1, 2),
        default=2,
        help="newest protocol version to offer (2; falls back to 1)",
    )
    p.add_argument(
        "--pose-rate",
        type=float,
        choices=(60.0, 30.0, 20.0, 15.0),
        default=None,
        help="v2: poses per second each headset receives (60)",
    )
    p.add_argument(
        "--layout", action="append", metavar="LAYOUT",
        help="what player i sends: hmd3+waist (default), hmd3, or a tracker set such as "
        "head,left_hand,right_hand,waist,left_foot:imu,right_foot:imu (repeatable: the "
        "players take them in turn)",
    )  # fmt: skip
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
        "tracker_set": tracker_set(layout_of(args, i)),
    }
    if args.bvh:
        return BvhReplaySource(args.bvh[i % len(args.bvh)], **options)
    return WalkSource(seconds=max(10.0, min(args.duration, 60.0)), **options)


def layout_of(args: argparse.Namespace, i: int) -> str:
    """The layout player ``i`` joins with (``--layout``, in turn)."""
    layouts = args.layout or [Layout.HMD3_WAIST.value]
    return str(layouts[i % len(layouts)])


async def _for(
    source: ReplaySource, seconds: float, *stops: asyncio.Event
) -> AsyncIterator[TrackerSample]:
    end = time.monotonic() + seconds
    async for sample in source:
        if time.monotonic() >= end or any(s.is_set() for s in stops):
            return
        yield sample


async def run_player(
    args: argparse.Namespace,
    i: int,
    report: PlayerReport,
    source: ReplaySource,
    stop: asyncio.Event,
    *,
    leave: asyncio.Event | None = None,
    seconds: float | None = None,
) -> None:
    """Join as ``report.player`` and stream ``source`` for ``seconds`` (``--duration``),
    or until ``stop`` or ``leave`` is set, then say ``bye``."""
    token = token_for(args, report.room, report.player)
    t_connect = time.monotonic()
    client = await connect_patiently(args.url, token, protocol=args.protocol)
    stops = (stop,) if leave is None else (stop, leave)
    try:
        await client.join(
            report.room,
            f"Sim {i}",
            layout=layout_of(args, i),
            rate_hz=min(args.rate, 120.0),
            pose_rate_hz=args.pose_rate,
        )
        report.version = client.version
        report.active = True
        frames = _for(source, args.duration if seconds is None else seconds, *stops)
        streaming = asyncio.create_task(client.stream(frames))
        async for event in client.events(until=streaming):
            if isinstance(event, Pose):
                report.poses += 1
                report.poses_from[event.player] = report.poses_from.get(event.player, 0) + 1
                sent = client.sent_at(event.seq) if event.player == client.player else None
                if sent is not None and report.first_pose_s is None:
                    report.first_pose_s = time.monotonic() - t_connect
                if sent is not None:
                    report.latencies_s.append(time.monotonic() - sent)
            elif isinstance(event, Error):
                report.errors.append(event.code)
            elif isinstance(event, Reconnecting):
                if event.attempt == 1:
                    report.losses += 1
                if not args.quiet:
                    print(f"{report.player}: reconnecting ({event.cause!r})", file=sys.stderr)
        await streaming
    finally:
        report.active = False
        report.frames_sent = client.stats.frames_sent
        report.frames_dropped = client.stats.frames_dropped
        report.reconnects = client.stats.reconnects
        report.pose_bytes = client.stats.pose_bytes
        report.clock_offset_s, report.rtt_s = client.clock.offset_s, client.clock.rtt_s
        await client.close()


def summarise(
    reports: Sequence[PlayerReport], seconds: float, args: argparse.Namespace
) -> dict[str, Any]:
    lat = np.array([x for r in reports for x in r.latencies_s]) * 1000.0
    offsets = [r.clock_offset_s for r in reports if r.clock_offset_s is not None]
    rtts = [r.rtt_s for r in reports if r.rtt_s is not None]
    first = np.array([r.first_pose_s for r in reports if r.first_pose_s is not None]) * 1000.0
    poses = sum(r.poses for r in reports)
    frames = sum(r.frames_sent for r in reports)
    return {
        "players": args.players,
        "rooms": args.rooms,
        "sessions": len(reports),
        "churned": sum(r.churned for r in reports),
        "seconds": round(seconds, 3),
        "frames_sent": frames,
        "frames_dropped": sum(r.frames_dropped for r in reports),
        "frames_per_s": round(frames / seconds, 1),
        "poses_received": poses,
        "poses_per_s": round(poses / seconds, 1),
        "protocol": sorted({r.version for r in reports if r.version}),
        "bytes_per_pose": round(sum(r.pose_bytes for r in reports) / poses, 2) if poses else None,
        "pose_kbytes_per_s": round(
            sum(r.pose_bytes for r in reports) / seconds / 1000 / max(1, len(reports)), 2
        ),
        "latency_ms_p50": round(float(np.percentile(lat, 50)), 2) if lat.size else None,
        "latency_ms_p99": round(float(np.percentile(lat, 99)), 2) if lat.size else None,
        "latency_samples": int(lat.size),
        "first_pose_ms_p50": round(float(np.percentile(first, 50)), 1) if first.size else None,
        "first_pose_ms_max": round(float(first.max()), 1) if first.size else None,
        "clock_offset_ms": round(float(np.median(offsets)) * 1000, 3) if offsets else None,
        "rtt_ms": round(float(np.median(rtts)) * 1000, 3) if rtts else None,
        "reconnects": sum(r.reconnects for r in reports),
        "connection_losses": sum(r.losses for r in reports),
        "errors": sum(len(r.errors) for r in reports),
        "error_codes": sorted({code for r in reports for code in r.errors}),
        "failed": {r.player: r.failure for r in reports if r.failure},
        "failure_codes": {r.player: r.failure_code for r in reports if r.failure},
        "failure_hints": {r.failure_code: r.failure_hint for r in reports if r.failure},
        "poses_from": {r.player: dict(sorted(r.poses_from.items())) for r in reports},
    }


def print_summary(s: dict[str, Any]) -> None:
    print(f"posecast-sim: {s['players']} players in {s['rooms']} rooms for {s['seconds']:.1f} s")
    sent, dropped = s["frames_sent"], s["frames_dropped"]
    print(f"  frames sent     {sent:8d}  ({s['frames_per_s']:.1f}/s, {dropped} dropped)")
    print(f"  poses received  {s['poses_received']:8d}  ({s['poses_per_s']:.1f}/s)")
    if s["bytes_per_pose"] is not None:
        v = "/".join(f"v{x}" for x in s["protocol"])
        print(f"  bytes per pose  {s['bytes_per_pose']:8.1f}  ({v}, WebSocket payload)")
    if s["latency_samples"]:
        print(
            f"  latency         p50 {s['latency_ms_p50']:.1f} ms  p99 {s['latency_ms_p99']:.1f} ms"
            "  (frame sent -> its pose received, look-ahead included)"
        )
    if s["clock_offset_ms"] is not None:
        print(f"  clock offset    {s['clock_offset_ms']:.3f} ms  (rtt {s['rtt_ms']:.3f} ms)")
    if s["first_pose_ms_p50"] is not None:
        p50, top = s["first_pose_ms_p50"], s["first_pose_ms_max"]
        print(f"  first own pose  p50 {p50:.0f} ms  max {top:.0f} ms  (from connecting)")
    if s["sessions"] != s["players"]:
        print(f"  sessions        {s['sessions']:8d}  ({s['churned']} left by the churn schedule)")
    print(
        f"  reconnects {s['reconnects']}, connection losses {s['connection_losses']}, "
        f"errors {s['errors']}, failed players {len(s['failed'])}"
    )
    for player, why in s["failed"].items():
        print(f"    {player}: {why}")


async def run_slot(
    args: argparse.Namespace,
    slot: Slot,
    players: Iterator[int],
    tag: str,
    reports: list[PlayerReport],
    stop: asyncio.Event,
) -> None:
    """Hold ``slot`` for ``--duration`` s: one player, then after each churn a new one
    (a fresh id and token) who replays the slot's motion: building a source takes
    long enough to stall every other player of this process, so it is built once.

    A player that fails, or whose session ends without being asked to leave, is not
    replaced: its failure is reported, not papered over by a rejoin.
    """
    end = time.monotonic() + args.duration
    source = make_source(args, slot.index, slot.place)
    while not stop.is_set() and (left := end - time.monotonic()) > 0:
        i = next(players)
        report = PlayerReport(player=f"sim-{tag}-{i}", room=slot.room)
        reports.append(report)
        slot.leave = asyncio.Event()
        try:
            await run_player(args, i, report, source, stop, leave=slot.leave, seconds=left)
        except Exception as exc:
            report.failure = repr(exc)
            with contextlib.suppress(Exception):  # an unforeseen one stays INTERNAL
                report.failure_code, _, report.failure_hint = describe(exc, args.url)
            return
        if not slot.leave.is_set():
            return
        report.churned = True


async def churn(slots: Sequence[Slot], every_s: float, stop: asyncio.Event) -> None:
    """Every ``every_s`` seconds ask the next slot's player to leave (slots take turns)."""
    for k in itertools.count():
        try:
            await asyncio.wait_for(stop.wait(), every_s)
            return
        except TimeoutError:
            slots[k % len(slots)].leave.set()


async def progress(
    reports: Sequence[PlayerReport], every_s: float, stop: asyncio.Event, t0: float
) -> None:
    """Print a progress line every ``every_s`` seconds (poses so far, players joined...)."""
    while True:
        try:
            await asyncio.wait_for(stop.wait(), every_s)
            return
        except TimeoutError:
            pass
        line = {
            "t_s": round(time.monotonic() - t0, 3),
            "active": sum(r.active for r in reports),
            "sessions": len(reports),
            "churned": sum(r.churned for r in reports),
            "poses": sum(r.poses for r in reports),
            "connection_losses": sum(r.losses for r in reports),
            "errors": sum(len(r.errors) for r in reports),
            "failed": sum(r.failure is not None for r in reports),
        }
        print("posecast-sim progress " + json.dumps(line), flush=True)


async def run(args: argparse.Namespace) -> dict[str, Any]:
    stop = asyncio.Event()
    stop_on_signals(stop)
    tag = unique_suffix()
    players = itertools.count()
    reports: list[PlayerReport] = []
    slots, tasks = [], []
    t0 = time.monotonic()
    helpers = []
    if args.progress_every > 0:
        helpers.append(asyncio.create_task(progress(reports, args.progress_every, stop, t0)))
    for i in range(args.players):
        slot = Slot(index=i, room=f"{args.room_prefix}-{i % args.rooms}", place=i // args.rooms)
        slots.append(slot)
        tasks.append(asyncio.create_task(run_slot(args, slot, players, tag, reports, stop)))
        await asyncio.sleep(0.01)  # stagger the handshakes a little
    if args.churn_every > 0:
        helpers.append(asyncio.create_task(churn(slots, args.churn_every, stop)))
    start = time.monotonic()
    await asyncio.gather(*tasks)
    for task in helpers:
        task.cancel()
    await asyncio.gather(*helpers, return_exceptions=True)
    return summarise(reports, max(1e-3, time.monotonic() - start), args)


def main(argv: Sequence[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    resolve_server(args, P)
    if args.token and args.players > 1:
        usage_error(P, "one --token is one player", "use --secret for several players")
    if args.players < 1 or args.rooms < 1 or not 0 < args.duration < math.inf:
        usage_error(P, "--players, --rooms and --duration must be positive", "e.g. --players 4")
    check_room(P, "--room-prefix", f"{args.room_prefix}-{args.rooms - 1}")
    if not 1 <= args.rate <= MAX_RATE_HZ:
        usage_error(
            P,
            f"--rate {args.rate} is not in [1, {MAX_RATE_HZ:g}] frames per second",
            "e.g. 60 (a server takes up to its max_rate_hz, 120 by default)",
        )
    if not (0 <= args.noise_m < math.inf and 0 <= args.noise_deg < math.inf):
        usage_error(P, "--noise-m and --noise-deg must be finite and not negative", "e.g. 0.002")
    if not 0 <= args.dropout < 1:
        usage_error(P, f"--dropout {args.dropout} is not a share in [0, 1)", "e.g. 0.05")
    if args.churn_every < 0 or args.progress_every < 0:
        usage_error(
            P, "--churn-every and --progress-every must not be negative", "0 turns either off"
        )
    if args.token and args.churn_every > 0:
        usage_error(P, "churn needs a fresh token per player", "use --secret instead of --token")
    for layout in args.layout or ():
        try:
            tracker_set(layout)
        except ValueError as exc:
            usage_error(P, f"--layout {layout!r}: {exc}", "hmd3+waist, hmd3, or a tracker set")
    for path in args.bvh or ():
        try:
            BvhReplaySource(path)  # a file, a rig it knows, a frame rate
        except (BvhError, OSError) as exc:
            code, message, hint = describe(exc, args.url)
            usage_error(P, message, hint, code)
    if args.json is not None and not args.json.parent.is_dir():
        usage_error(P, f"--json {args.json}: no directory {args.json.parent}", "create it first")
    summary = asyncio.run(run(args))
    print_summary(summary)
    if args.json is not None:
        args.json.write_text(json.dumps(summary, indent=1) + "\n", encoding="utf-8")
    codes = list(summary["failure_codes"].values())
    if codes:  # the commonest failure, with its code and hint
        code = max(set(codes), key=codes.count)
        failed = f"{len(codes)} of {summary['sessions']} player sessions failed"
        print_error(P, code, failed, summary["failure_hints"][code] or "see the failures above")
    return 1 if summary["failed"] else 0


if __name__ == "__main__":  # pragma: no cover
    raise SystemExit(main())
