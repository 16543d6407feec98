"""``posecast bench latency``: a real ``posecast serve`` subprocess, Python SDK players
in client processes on loopback, and every pose's capture-to-display time split into
its budget (:mod:`.budget`); optionally again with every player behind the
reliability suite's lossy relay (:mod:`posecast.testing.relay`).

A run is one or two phases on one server: the clean phase, then (``lossy``) the same
players, fresh connections, each through the relay (``drop`` of its frames lost and
every message held ``0..jitter_s`` on the way in, and, if asked, ``0..down_jitter_s``
on the way out, in order). A phase starts the client
processes (:mod:`.players`, Python SDK players; or, ``sdk="typescript"``, Node
processes running the TypeScript SDK, :mod:`.node_players`), lets the players join
and stream for ``warmup_s``, then measures ``seconds``: the frames captured in that
window, the poses made from them (as every room-mate displayed them), the server's
``/metrics`` and CPU at both ends.
"""

from __future__ import annotations

import asyncio
import contextlib
import multiprocessing as mp
import os
import secrets
import tempfile
import threading
import time
from collections.abc import Callable, Iterator, Sequence
from dataclasses import asdict, dataclass
from enum import StrEnum
from pathlib import Path
from typing import Any

import numpy as np

from posecast.offline.evaluation.latency.budget import budget, stats_ms, summary
from posecast.offline.evaluation.latency.display import Displayed
from posecast.offline.evaluation.latency.node_players import (
    build_worker,
    node_workers,
    walk_seconds,
    write_walks,
)
from posecast.offline.evaluation.latency.players import (
    TAIL_S,
    PlayerPlan,
    WorkerPlan,
    WorkerResult,
    run_worker,
)
from posecast.testing.relay import LossyRelay
from posecast.testing.serve import Metrics, ServeProcess

START_S = 3.0  # from starting the client processes to the first frame: spawn, connect, join


class Sdk(StrEnum):
    """The SDK the players run: the Python SDK in Python processes, or the TypeScript
    SDK in Node processes (the same roles, walks, display loop and report)."""

    PYTHON = "python"
    TYPESCRIPT = "typescript"


@dataclass(frozen=True)
class LatencyConfig:
    """One ``posecast bench latency`` run (defaults as the command's).

    Args:
        players: SDK players, dealt into rooms of ``room_size`` in order.
        seconds: the measured window; ``warmup_s`` of streaming comes before it.
        display_hz: each receiver's display rate, sampling its interpolator.
        procs: client processes the players are dealt over (round robin).
        samples, lookahead, frame_queue: the server's ``--samples``, ``--lookahead``
            and ``--frame-queue`` (``None``: its defaults, what ``posecast serve`` runs).
        lossy: also run the phase behind the lossy relay, ``drop`` of the frames lost
            and ``jitter_s`` of uplink jitter (the reliability suite's 0.2 and 40 ms),
            and ``down_jitter_s`` of in-order downlink jitter (0, as the suite).
        seed: seeds the relay's faults.
        draw_all: every player samples its room-mates' poses each display frame; by
            default one player per room in each client process does (the joint jumps
            are theirs) and the others ask their interpolators only for the times
            they would show (``Interpolator.advance``: the same render delay).
        protocol: the newest protocol the SDK offers (2: ``posecast.v2``).
        sdk: the players' SDK (:class:`Sdk`): Python (default) or TypeScript, whose
            client processes are Node processes (``node`` and the SDK's
            ``node_modules`` needed).
    """

    players: int = 16
    room_size: int = 8
    seconds: float = 10.0
    warmup_s: float = 3.0
    display_hz: float = 90.0
    procs: int = 2
    samples: int | None = None
    lookahead: int | None = None
    frame_queue: int | None = None
    delayed_emission: bool = False  # the paper's emission of frame n - tau (serve's flag)
    lossy: bool = False
    drop: float = 0.2
    jitter_s: float = 0.040
    down_jitter_s: float = 0.0
    seed: int = 7
    protocol: int = 2
    draw_all: bool = False
    sdk: Sdk = Sdk.PYTHON


def _deal(cfg: LatencyConfig, prefix: str) -> list[tuple[PlayerPlan, ...]]:
    """The players, dealt into rooms in order and over the client processes round robin."""
    players = [
        PlayerPlan(f"{prefix}{i}", f"{prefix}room{i // cfg.room_size}", i % cfg.room_size, i)
        for i in range(cfg.players)
    ]
    procs = max(1, min(cfg.procs, cfg.players))
    return [tuple(players[k::procs]) for k in range(procs)]


def worker_plans(cfg: LatencyConfig, url: str, secret: str, prefix: str) -> list[WorkerPlan]:
    start_at = time.monotonic() + START_S + 0.05 * cfg.players
    measure_from = start_at + cfg.warmup_s
    return [
        WorkerPlan(url, secret, players, start_at, measure_from,
                   measure_from + cfg.seconds, cfg.display_hz, protocol=cfg.protocol,
                   draw_all=cfg.draw_all)
        for players in _deal(cfg, prefix)
    ]  # fmt: skip


def _delta(m0: Metrics, m1: Metrics, series: str) -> float:
    return m1.get(series, 0.0) - m0.get(series, 0.0)


Workers = contextlib.AbstractContextManager[Callable[[float], list[WorkerResult]]]


@contextlib.contextmanager
def _python_workers(plans: Sequence[WorkerPlan]) -> Iterator[Callable[[float], list[WorkerResult]]]:
    """One Python client process per plan; yields ``results(timeout_s)``."""
    with mp.get_context("spawn").Pool(len(plans)) as pool:
        pending = pool.map_async(run_worker, plans)
        yield lambda timeout_s: pending.get(timeout=timeout_s)


def _phase(
    cfg: LatencyConfig,
    server: ServeProcess,
    url: str,
    secret: str,
    prefix: str,
    node: Path | None = None,
) -> Any:
    """Run one phase's client processes against ``url``; its figures. ``node``: the
    bundled TypeScript worker (``sdk="typescript"``), its folder the phase's scratch."""
    walks = None
    if node is not None:  # the walks first: writing them must not eat into START_S
        seconds = walk_seconds(cfg.warmup_s, cfg.seconds)
        walks = [write_walks(players, node.parent / f"{prefix}walks{k}.f64", seconds=seconds)
                 for k, players in enumerate(_deal(cfg, prefix))]  # fmt: skip
    plans = worker_plans(cfg, url, secret, prefix)
    measure_from, stop_at = plans[0].measure_from, plans[0].stop_at
    workers: Workers = (
        _python_workers(plans)
        if node is None or walks is None
        else node_workers(node, plans, walks, node.parent)
    )
    with workers as results_of:
        time.sleep(max(0.0, measure_from - time.monotonic()))
        m0, cpu0, t0 = server.metrics(), server.cpu_seconds(), time.monotonic()
        time.sleep(max(0.0, stop_at - time.monotonic()))
        m1, cpu1, t1 = server.metrics(), server.cpu_seconds(), time.monotonic()
        results = results_of(START_S + cfg.seconds + 120)
    server_cores = (cpu1 - cpu0) / (t1 - t0)
    return report_of(results, m0, m1, server_cores, (measure_from, stop_at))


def report_of(
    results: Sequence[WorkerResult],
    m0: Metrics,
    m1: Metrics,
    server_cores: float,
    window: tuple[float, float],
) -> dict[str, Any]:
    """One phase's figures, from what its client processes and the server measured."""
    captures: dict[str, dict[int, float]] = {}
    rooms: dict[str, str] = {}
    displayed: list[Displayed] = []
    drawn: list[Displayed] = []  # those of the players that sampled every frame
    waiting, jumps, failures = [], [], []
    for r in results:
        captures.update(r.captures)
        rooms.update(r.members)
        displayed.extend(Displayed(*row) for row in r.displayed)
        drawn.extend(Displayed(*row) for row in r.displayed[: r.drawn])
        waiting.extend(r.waiting)
        jumps.extend(r.jumps_m)
        failures.extend(r.failures)
    welcome = results[0].welcome
    lookahead_s = welcome["lookahead_frames"] / welcome["rate_hz"]
    ticks = _delta(m0, m1, "posecast_tick_seconds_count")
    tick_s = _delta(m0, m1, "posecast_tick_seconds_sum") / ticks if ticks else 0.0
    b = budget(displayed, captures, lookahead_s=lookahead_s, tick_s=tick_s, window=window)
    # The drawing players' poses of the window (``drawn`` holds their warm-up and tail too).
    bd = budget(drawn, captures, lookahead_s=lookahead_s, tick_s=tick_s, window=window)
    d = stats_ms(bd.total)

    def in_window(sender: str, seq: int) -> bool:
        capture = captures.get(sender, {}).get(seq)
        return capture is not None and window[0] <= capture < window[1]

    members = {room: sum(1 for r in rooms.values() if r == room) for room in set(rooms.values())}
    expected = sum(
        (members[rooms[p]] - 1) * sum(1 for c in seqs.values() if window[0] <= c < window[1])
        for p, seqs in captures.items()
    )
    never = sum(1 for sender, seq, _, _ in waiting if in_window(sender, seq))
    # pose.t - capture - look-ahead: from capture to the start of the step that took the
    # frame; over a tick period, the frame waited behind another in its player's queue.
    waited = b.parts["server_queue_tick"] - tick_s
    held = float(np.mean(waited > 1.0 / welcome["rate_hz"])) if b.count else None
    frames = sum(r.display_frames for r in results)
    jumps_cm = np.array(jumps) * 100.0
    return {
        **summary(b),
        "poses_expected": expected,
        "poses_received_not_displayed": never,
        "drawn_capture_to_display_ms": {"p50": d["p50"], "p99": d["p99"], "poses": bd.count},
        "delivery": round(b.count / expected, 4) if expected else None,
        "lookahead_frames": welcome["lookahead_frames"],
        "rate_hz": welcome["rate_hz"],
        "protocol": welcome["version"],
        "tick_ms_mean": round(1000.0 * tick_s, 3),
        "queue_held_share": None if held is None else round(held, 4),
        "tick_overruns": _delta(m0, m1, "posecast_tick_overruns_total"),
        "frames_superseded": _delta(m0, m1, 'posecast_frames_dropped_total{reason="superseded"}'),
        "poses_superseded": _delta(m0, m1, "posecast_poses_superseded_total"),
        "max_joint_jump_cm": _round(jumps_cm.max()) if len(jumps_cm) else None,
        "p99_joint_jump_cm": _round(np.percentile(jumps_cm, 99)) if len(jumps_cm) else None,
        "display_frames": frames,
        "display_frames_late_share": round(
            sum(r.display_frames_late for r in results) / frames, 4
        ) if frames else None,
        "server_cpu_cores": round(server_cores, 3),
        "clients_cpu_cores": round(sum(r.cpu_s / r.wall_s for r in results if r.wall_s), 3),
        "errors": dict(sum((r.errors for r in results), start=type(results[0].errors)())),
        "failures": failures,
    }  # fmt: skip


@contextlib.contextmanager
def _relay(upstream: str, cfg: LatencyConfig) -> Iterator[LossyRelay]:
    """The lossy relay in front of ``upstream``, on an event loop of its own thread
    (this process only waits while the clients run)."""
    from posecast.online.protocol.messages import SUBPROTOCOL, SUBPROTOCOL_V2

    relay = LossyRelay(upstream, drop=cfg.drop, jitter_s=cfg.jitter_s, seed=cfg.seed,
                       protocols=(SUBPROTOCOL_V2, SUBPROTOCOL),
                       down_jitter_s=cfg.down_jitter_s)  # fmt: skip
    loop = asyncio.new_event_loop()
    thread = threading.Thread(target=loop.run_forever, name="lossy-relay", daemon=True)
    thread.start()
    try:
        asyncio.run_coroutine_threadsafe(relay.start(), loop).result(10)
        yield relay
    finally:
        with contextlib.suppress(Exception):
            asyncio.run_coroutine_threadsafe(relay.stop(), loop).result(10)
        loop.call_soon_threadsafe(loop.stop)
        thread.join(10)
        loop.close()


def run_latency(cfg: LatencyConfig) -> dict[str, Any]:
    """Run the benchmark; the report (see ``docs/latency-benchmark.md``)."""
    secret = secrets.token_hex(24)
    flags = ["--delayed-emission"] if cfg.delayed_emission else []
    if cfg.frame_queue is not None:
        flags += ["--frame-queue", str(cfg.frame_queue)]
    server = ServeProcess(
        "--conn-per-ip-per-min", "100000", "--sockets-per-ip", "100000", *flags,
        secret=secret, samples=cfg.samples, lookahead=cfg.lookahead,
    )  # fmt: skip
    scratch = tempfile.TemporaryDirectory(prefix="posecast-latency-")
    try:
        # The TypeScript worker is bundled once, before the server's clock matters.
        node = build_worker(Path(scratch.name)) if cfg.sdk is Sdk.TYPESCRIPT else None
        server.wait_ready(timeout_s=60.0)
        report: dict[str, Any] = {
            "config": asdict(cfg),
            "machine_cores": os.cpu_count(),
            "tail_s": TAIL_S,
            **_phase(cfg, server, server.url, secret, "p", node),
        }
        if cfg.lossy:
            with _relay(server.url, cfg) as relay:
                lossy = _phase(cfg, server, relay.url, secret, "q", node)
                st = relay.stats
            lossy["relay"] = {
                "drop": cfg.drop,
                "jitter_ms": round(cfg.jitter_s * 1000.0, 1),
                "down_jitter_ms": round(cfg.down_jitter_s * 1000.0, 1),
                "frames_in": st.frames_in,
                "frames_dropped": st.frames_dropped,
                "frames_reordered": st.frames_reordered,
            }
            lossy["p99_vs_clean"] = ratio(
                lossy["capture_to_display_ms_p99"], report["capture_to_display_ms_p99"]
            )
            lossy["max_joint_jump_vs_clean"] = ratio(
                lossy["max_joint_jump_cm"], report["max_joint_jump_cm"]
            )
            report["lossy"] = lossy
    finally:
        server.stop(timeout_s=15)
        scratch.cleanup()
    return report


def _round(x: Any) -> float:
    return round(float(x), 2)


def ratio(a: float | None, b: float | None) -> float | None:
    return None if a is None or not b else round(a / b, 3)
