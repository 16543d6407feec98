"""``load.py soak``: players joining and leaving for a while; the server's memory, file
descriptors and asyncio tasks sampled, and the checks of ``load.py``'s docstring."""

from __future__ import annotations

import argparse
import os
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from load_report import pinning, print_soak_window
from load_rig import (
    Server,
    Sim,
    Snapshot,
    criteria,
    expected_poses_per_s,
    losses,
    players_in,
    serve,
    version,
    wait_players,
    window,
)
from posecast.testing.serve import Metrics, metric_sum


@dataclass
class Sample:
    t_s: float  # since measured time began (all players joined)
    rss_mb: float
    fds: int
    tasks: int
    players: int
    connections: int


@dataclass
class SoakState:
    samples: list[Sample] = field(default_factory=list)
    windows: list[dict[str, Any]] = field(default_factory=list)


def _sample(server: Server, t0: float) -> Sample:
    m = server.metrics()
    conns = sum(v for k, v in m.items() if k.startswith("posecast_connections{"))
    return Sample(
        t_s=round(time.monotonic() - t0, 1),
        rss_mb=round(server.rss_bytes() / 2**20, 2),
        fds=server.fds(),
        tasks=int(metric_sum(m, "posecast_asyncio_tasks")),
        players=players_in(m),
        connections=int(conns),
    )


def _idle(server: Server, timeout_s: float, like: Sample | None = None) -> Sample:
    """Wait until no client is connected (and, given ``like``, until FDs and tasks are
    back to its values, for at most ``timeout_s``); then sample."""
    deadline = time.monotonic() + timeout_s
    s = _sample(server, time.monotonic())
    while time.monotonic() < deadline:
        s = _sample(server, time.monotonic())
        settled = s.connections == 0 and s.players == 0
        if settled and (like is None or (s.fds <= like.fds and s.tasks <= like.tasks)):
            break
        time.sleep(0.5)
    return s


def soak(args: argparse.Namespace, workdir: Path) -> dict[str, Any]:
    st = SoakState()
    procs = max(1, min(args.procs, args.players))
    shares = [len(range(i, args.players, procs)) for i in range(procs)]
    sims: list[Sim] = []
    with serve(args.samples, workdir, args.server_arg, args.server_cpus) as server:
        time.sleep(1.0)
        before = _idle(server, 5.0)
        # Each process churns its own players; together one leave every --churn-every s.
        spare = 60.0 + args.join_timeout
        for i, n in enumerate(shares):
            sims.append(
                Sim.start(
                    server,
                    workdir,
                    f"soak{i}",
                    n,
                    args.room_size,
                    args.seconds + spare,
                    churn_every_s=args.churn_every * procs,
                    progress_every_s=1.0,
                    seed=1000 * i,
                    cpus=args.client_cpus,
                    nice=args.client_nice,
                )
            )
            time.sleep(args.churn_every)  # spread the processes' churn schedules
        try:
            joined = wait_players(server, args.players - procs, args.join_timeout)
            t0 = time.monotonic()
            expected = expected_poses_per_s(sims)
            a = Snapshot.take(server, sims)
            next_window, next_sample = t0 + args.window, t0
            end = t0 + args.seconds
            while True:
                now = time.monotonic()
                if now >= next_sample - 0.01:
                    st.samples.append(_sample(server, t0))
                    next_sample += args.sample_every
                if now >= next_window - 0.01:
                    b = Snapshot.take(server, sims)
                    w = {"t_end_s": round(b.t - t0, 1), **window(a, b, expected)}
                    s = st.samples[-1]
                    w.update(
                        rss_mb=s.rss_mb,
                        fds=s.fds,
                        tasks=s.tasks,
                        players=s.players,
                        connection_losses=losses(sims),
                    )
                    st.windows.append(w)
                    print_soak_window(w, header=len(st.windows) == 1)
                    a, next_window = b, next_window + args.window
                if now >= end - 0.01:
                    break
                time.sleep(max(0.0, min(next_sample, next_window, end) - time.monotonic()))
        finally:
            summaries = [s.stop() for s in sims]
        after = _idle(server, 30.0, like=before)
        metrics = server.metrics()
        alive = server.alive()
        problems = server.log_problems()
    return _soak_report(args, st, summaries, before, after, metrics, alive, joined, problems)


def _soak_report(
    args: argparse.Namespace,
    st: SoakState,
    summaries: list[dict[str, Any]],
    before: Sample,
    after: Sample,
    metrics: Metrics,
    alive: bool,
    joined: bool,
    problems: list[str],
) -> dict[str, Any]:
    warm = [s for s in st.samples if s.t_s >= args.warmup] or st.samples[-1:]
    rss0, rss1 = warm[0].rss_mb, warm[-1].rss_mb
    growth = 100.0 * (rss1 - rss0) / rss0
    sessions = sum(int(s.get("sessions", 0)) for s in summaries)
    churned = sum(int(s.get("churned", 0)) for s in summaries)
    losses = sum(int(s.get("connection_losses", 0)) for s in summaries)
    failed = {k: v for s in summaries for k, v in s.get("failed", {}).items()}
    errors = sum(int(s.get("errors", 0)) for s in summaries)
    accepted = int(metrics.get('posecast_connects_total{result="accepted"}', 0.0))
    extra_connections = max(0, accepted - sessions)  # reconnects the clients did not count
    unexplained = losses + len(failed) + extra_connections
    fds, tasks = [s.fds for s in warm], [s.tasks for s in warm]
    warm_windows = [w for w in st.windows if w["t_end_s"] > args.warmup] or st.windows
    worst_delivery = min((w["delivery"] for w in warm_windows), default=0.0)
    checks = {
        "all_joined": joined,
        "rss_growth": growth <= args.max_rss_growth,
        "fds_under_load": max(fds) - min(fds) <= args.fd_slack,
        "tasks_under_load": max(tasks) - min(tasks) <= args.task_slack,
        "fds_back_to_idle": after.fds <= before.fds,
        "tasks_back_to_idle": after.tasks <= before.tasks,
        "no_unexplained_disconnects": unexplained == 0 and errors == 0,
        "poses_flowing": bool(st.windows) and worst_delivery >= args.min_delivery,
        "server_alive": alive,
    }
    report = {
        "mode": "soak",
        "samples": args.samples,
        "players": args.players,
        "room_size": args.room_size,
        "client_processes": len(summaries),
        "seconds": args.seconds,
        "warmup_s": args.warmup,
        "churn_every_s": args.churn_every,
        "machine_cores": os.cpu_count(),
        "pinning": pinning(args),
        "windows": st.windows,
        "tick_ms_p99_worst_window": max((w["tick_ms_p99"] for w in st.windows), default=None),
        "ticks_over_16_7ms_worst_window": max(
            (w["ticks_over_16_7ms"] for w in st.windows), default=None
        ),
        "rss_mb_idle_before": before.rss_mb,
        "rss_mb_start": rss0,
        "rss_mb_end": rss1,
        "rss_mb_peak": max(s.rss_mb for s in st.samples),
        "rss_growth_pct": round(growth, 2),
        "fds_idle_before": before.fds,
        "fds_under_load_min_max": [min(fds), max(fds)],
        "fds_idle_after": after.fds,
        "tasks_idle_before": before.tasks,
        "tasks_under_load_min_max": [min(tasks), max(tasks)],
        "tasks_idle_after": after.tasks,
        "sessions": sessions,
        "expected_disconnects": sessions,  # every session ends: a churn leave or the last
        "churn_leaves": churned,
        "server_accepted_connections": accepted,
        "connection_losses": losses,
        "failed_players": failed,
        "error_messages": errors,
        "unexplained_disconnects": unexplained,
        "poses_received": sum(int(s.get("poses_received", 0)) for s in summaries),
        "first_pose_ms_p50": [s.get("first_pose_ms_p50") for s in summaries],
        "first_pose_ms_max": [s.get("first_pose_ms_max") for s in summaries],
        "frames_sent": sum(int(s.get("frames_sent", 0)) for s in summaries),
        "delivery_worst_window": worst_delivery,
        "server_log_lines": problems[-20:],
        "server_alive": alive,
        "checks": checks,
        "ok": all(checks.values()),
        "criteria": {
            "rss_growth_pct_max": args.max_rss_growth,
            "fd_slack": args.fd_slack,
            "task_slack": args.task_slack,
            "sustainable_tick": criteria(),
        },
        "samples_over_time": [s.__dict__ for s in st.samples],
        "version": version(),
    }
    return report
