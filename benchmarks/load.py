"""Load and soak: simulated players against a real ``posecast serve``.

    python benchmarks/load.py ramp --samples 100 --room-size 8 --step 4 --json ramp-n100.json
    python benchmarks/load.py ramp --clients sdk --samples 100 --step 4    # SDK clients
    python benchmarks/load.py soak --samples 10 --players 64 --seconds 600 \\
                                   --churn-every 3 --json soak.json

Both start the server as a subprocess (``python -m posecast serve --port 0``) on the
same machine as the clients, which share its cores: the clients' CPU is measured and
printed beside the server's, and the machine's other load (``other_cores``) too.
``--server-cpus``/``--client-cpus`` pin them apart, ``--client-nice`` lowers the
clients' priority.

The ramp's clients (``--clients``):

* ``lean`` (the default): every player in one ``lean_clients.py`` process (one
  asyncio loop on ``websockets``; frames pre-encoded once per player, 60 Hz, seq
  counting up; poses counted, never decoded), so that the load generator takes as
  little of the server's CPU as it can: about 0.008 of a core per player (0.15 at 20
  players), against 0.025 for SDK clients. ``--protocol 2`` (the default) speaks
  ``posecast.v2`` as the SDKs do (one ``poses`` message of pose records per tick, the
  records counted by walking their lengths); ``--protocol 1`` speaks ``posecast.v1``
  (a ``pose`` message per avatar per tick, counted from its first bytes). Rooms are filled in
  order across steps, so ``--room-size 8 --step 4`` really gives rooms of 8. It
  reports its own CPU (``process_time`` over wall time) and, per player, the poses
  received against the expected ``welcome.rate_hz x room members x seconds``.
* ``sdk``: one ``posecast-sim`` process per step (the SDK's simulator: each player a
  real SDK ``Client`` replaying the built-in procedural walk, receiving and decoding
  every room-mate's pose), in rooms of at most ``--room-size`` within that step's
  players (``--step 4`` gives rooms of 4). A Python SDK client costs about 0.02-0.03
  of a core per player, so on a small machine the clients take as much CPU as the
  server. The soak always uses these.

**ramp** adds ``--step`` players at a time, waits until they have joined and
``--settle`` seconds more, then measures a ``--window`` of seconds from the server's
``/metrics`` (differences of the counters over the window). A step is *sustainable*
when, over its window:

* at most 1 % of ticks took longer than 16.7 ms (one 60 Hz period): tick p99 <= 16.7 ms;
  the histogram has a bucket edge at 0.0167 s, so this is read exactly, not estimated;
* at most 1 % of ticks overran (started a whole period late, ``posecast_tick_overruns``);
* ticks ran at >= 59 per second;
* (lean clients) the players received >= 99 % of the poses expected
  (``load_rig.lean_window``);
* every player had joined and no client lost its connection.

The maximum sustainable players is the largest step such that it and every step
below it were sustainable. The ramp stops after two unsustainable steps in a row or
at ``--max-players``. Tick p50/p99 in the table are interpolated within the
histogram's buckets (..., 8, 12, 16.7, 25, 50 ms), as Prometheus' histogram_quantile
does, so they are coarse; the share of ticks over 16.7 ms is exact.

**soak** runs ``--players`` players for ``--seconds`` while one of them leaves (``bye``)
and a new player takes its place every ``--churn-every`` seconds (``posecast-sim
--churn-every``). Every ``--sample-every`` seconds it reads the server's resident
memory (``/proc/PID/status`` VmRSS), open file descriptors (``/proc/PID/fd``) and asyncio
tasks (``posecast_asyncio_tasks``); per ``--window`` it prints tick p50/p99, overruns,
CPU and the poses the clients received. Measured time starts once every player has
joined; the first ``--warmup`` seconds of it are warm-up (RSS "start" is the first
sample after it, RSS "end" the last sample before the clients stop). Checks:

* RSS grew by at most ``--max-rss-growth`` % (5) from start to end;
* FDs and tasks under load stayed within what the churn explains (one connection in
  transition: the largest value after warm-up at most ``--fd-slack`` / ``--task-slack``
  above the smallest), and came back to their idle values before the load, once the
  clients had gone;
* no unexplained disconnect: no client lost its connection or failed, no error
  message reached a client, and the server accepted exactly one connection per
  client session (a reconnect would add one). Expected disconnects are the churn's
  leaves plus the final leave of every player;
* poses flowed: in every window after warm-up the clients received at least
  ``--min-delivery`` (50 %) of the poses full rooms would get (60 Hz x room size per
  player; each churn costs the room the new player's first poses, which take
  ``first_pose_ms`` from connecting to arrive), and the server answered ``/healthz``
  at the end.

It prints its figures, writes them with ``--json``, and exits 1 when a check failed.
The processes and the window arithmetic are in ``load_rig.py``, the lean generator
in ``lean_clients.py``.
"""

from __future__ import annotations

import argparse
import json
import os
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from load_rig import (
    MIN_DELIVERY,
    LeanClients,
    Metrics,
    Server,
    Sim,
    Snapshot,
    criteria,
    expected_poses_per_s,
    lean_window,
    losses,
    parse_cpus,
    players_in,
    serve,
    sustainable,
    version,
    wait_players,
    window,
)
from posecast.testing.serve import metric_sum

# --- ramp ----------------------------------------------------------------------------------


class RampLoad:
    """The ramp's clients: ``add`` players, take a :class:`Snapshot`, read a window."""

    def __init__(self, args: argparse.Namespace, server: Server, workdir: Path) -> None:
        self.args, self.server, self.workdir = args, server, workdir
        self.players = 0
        self.sims: list[Sim] = []
        self.lean: LeanClients | None = None
        if args.clients == "lean":
            cpus, nice = args.client_cpus, args.client_nice
            self.lean = LeanClients.start(
                server, workdir, args.room_size, protocol=args.protocol, cpus=cpus, nice=nice
            )

    def add(self, n: int) -> bool:
        """``n`` more players; whether every player has joined (the server's count)."""
        self.players += n
        if self.lean is not None:
            self.lean.add(n, self.args.join_timeout)
        else:
            step = len(self.sims)
            self.sims.append(
                Sim.start(
                    self.server, self.workdir, f"ramp{step}", n, self.args.room_size, 3600.0,
                    seed=1000 * step, cpus=self.args.client_cpus, nice=self.args.client_nice,
                )
            )  # fmt: skip
        return wait_players(self.server, self.players, self.args.join_timeout)

    def snapshot(self) -> Snapshot:
        return Snapshot.take(self.server, self.sims, self.lean)

    def window(self, a: Snapshot, b: Snapshot) -> dict[str, Any]:
        if self.lean is None:
            row = window(a, b, expected_poses_per_s(self.sims))
            row["connection_losses"] = losses(self.sims)
            return row
        assert a.lean is not None and b.lean is not None
        lean = lean_window(a.lean, b.lean)
        row = window(a, b, lean["expected_poses_per_s"])
        row.update(lean)  # its delivery is per player, on the generator's own clock
        row["connection_losses"] = b.lean["connection_losses"]
        return row

    def stop(self) -> list[dict[str, Any]]:
        if self.lean is not None:
            return [self.lean.stop()]
        return [s.stop() for s in self.sims]


def ramp(args: argparse.Namespace, workdir: Path) -> dict[str, Any]:
    rows: list[dict[str, Any]] = []
    failing = 0
    min_delivery = MIN_DELIVERY if args.clients == "lean" else None
    clients = f"lean, posecast.v{args.protocol}" if args.clients == "lean" else args.clients
    print(f"ramp: N={args.samples}, rooms of {args.room_size}, +{args.step} players a step, "
          f"clients {clients}", flush=True)  # fmt: skip
    with serve(args.samples, workdir, args.server_arg, args.server_cpus) as server:
        load = RampLoad(args, server, workdir)
        try:
            while True:
                joined = load.add(args.step)
                time.sleep(args.settle)
                a = load.snapshot()
                time.sleep(args.window)
                b = load.snapshot()
                row = {
                    "players": load.players,
                    "joined": players_in(b.metrics),
                    **load.window(a, b),
                }
                row["client_cpu_per_player"] = round(row["client_cpu_cores"] / load.players, 4)
                row["sustainable"] = (
                    joined and row["connection_losses"] == 0 and sustainable(row, min_delivery)
                )
                rows.append(row)
                _print_ramp_row(row, header=len(rows) == 1)
                if row.get("workers"):
                    print("        workers: " + "; ".join(
                        f"{w}: {t['players']} players, tick p99 {t['tick_ms_p99']:.1f} ms, "
                        f"{t['ticks_over_16_7ms']:.1%} over"
                        for w, t in row["workers"].items()), flush=True)  # fmt: skip
                if row.get("generator_late_ticks"):
                    print(
                        f"        the lean generator sent {row['generator_late_ticks']} of its "
                        f"{row['generator_ticks']} ticks a period late: the clients fell behind",
                        flush=True,
                    )
                failing = 0 if row["sustainable"] else failing + 1
                if failing >= 2 or load.players + args.step > args.max_players:
                    break
        finally:
            summaries = load.stop()
        alive = server.alive()
    best = 0
    for row in rows:
        if not row["sustainable"]:
            break
        best = row["players"]
    return {
        "mode": "ramp",
        "clients": args.clients,
        "protocol": args.protocol if args.clients == "lean" else None,
        "samples": args.samples,
        "room_size": args.room_size,
        "step": args.step,
        "window_s": args.window,
        "machine_cores": os.cpu_count(),
        "pinning": _pinning(args),
        "criteria": criteria(min_delivery),
        "rows": rows,
        "max_sustainable_players": best,
        "server_alive": alive,
        "client_failures": sum(len(s.get("failed", {})) for s in summaries),
        "version": version(),
    }


def _clients(report: dict[str, Any]) -> str:
    if report["clients"] == "lean":
        return f"lean clients (posecast.v{report['protocol']})"
    return f"{report['clients']} clients"


def _pinning(args: argparse.Namespace) -> dict[str, Any]:
    return {
        "server_cpus": sorted(args.server_cpus or []) or "any",
        "client_cpus": sorted(args.client_cpus or []) or "any",
        "client_nice": args.client_nice,
        "server_args": args.server_arg,
    }


def _print_ramp_row(row: dict[str, Any], header: bool) -> None:
    """One step. ``clients`` is their CPU from ``/proc``; ``gen`` the lean generator's
    own ``process_time`` share and ``worst`` its lowest player's delivery (lean only)."""
    if header:
        print("players tick p50    p99 >16.7ms overrun tick Hz server clients   gen other"
              "  deliv  worst  ok")  # fmt: skip
        print("              ms     ms   share   share          cores   cores cores cores")
    lean = "generator_cpu_cores" in row
    gen = f"{row['generator_cpu_cores']:5.2f}" if lean else "    -"
    worst = _share(row.get("delivery_worst"))
    print(
        f"{row['players']:7d} {row['tick_ms_p50']:8.2f} {row['tick_ms_p99']:6.2f} "
        f"{row['ticks_over_16_7ms']:7.2%} {row['overrun_share']:7.2%} {row['tick_hz']:7.2f} "
        f"{row['server_cpu_cores']:6.2f} {row['client_cpu_cores']:7.2f} {gen} "
        f"{row['other_cpu_cores']:5.2f} {_share(row['delivery'])} {worst}  "
        f"{'yes' if row['sustainable'] else 'NO'}",
        flush=True,
    )


def _share(value: float | None) -> str:
    return "     -" if value is None else f"{value:6.1%}"


# --- soak ----------------------------------------------------------------------------------


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
                    _print_soak_window(w, header=len(st.windows) == 1)
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
        "pinning": _pinning(args),
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


def _print_soak_window(w: dict[str, Any], header: bool) -> None:
    if header:
        print(
            f"{'t s':>6} {'tick p50':>8} {'p99':>6} {'>16.7ms':>7} {'overruns':>8} "
            f"{'server':>6} {'clients':>7} {'poses/s':>8} {'deliv':>6} {'RSS MB':>7} "
            f"{'FDs':>4} {'tasks':>5} {'players':>7} {'lost':>4}"
        )
    print(
        f"{w['t_end_s']:6.0f} {w['tick_ms_p50']:8.2f} {w['tick_ms_p99']:6.2f} "
        f"{w['ticks_over_16_7ms']:7.2%} {w['overruns']:8d} {w['server_cpu_cores']:6.2f} "
        f"{w['client_cpu_cores']:7.2f} {w['poses_received_per_s']:8.0f} {w['delivery']:6.1%} "
        f"{w['rss_mb']:7.1f} {w['fds']:4d} {w['tasks']:5d} {w['players']:7d} "
        f"{w['connection_losses']:4d}",
        flush=True,
    )


def _print_soak_summary(r: dict[str, Any]) -> None:
    print(
        f"soak: {r['players']} players, N={r['samples']}, rooms of {r['room_size']}, "
        f"{r['seconds']:.0f} s, one leave+join every {r['churn_every_s']:g} s"
    )
    print(
        f"  RSS      {r['rss_mb_start']:.1f} MB after {r['warmup_s']:g} s warm-up -> "
        f"{r['rss_mb_end']:.1f} MB at the end ({r['rss_growth_pct']:+.2f} %), "
        f"peak {r['rss_mb_peak']:.1f}, idle before {r['rss_mb_idle_before']:.1f}"
    )
    print(
        f"  FDs      idle {r['fds_idle_before']} -> under load "
        f"{r['fds_under_load_min_max']} -> idle after {r['fds_idle_after']}"
    )
    print(
        f"  tasks    idle {r['tasks_idle_before']} -> under load "
        f"{r['tasks_under_load_min_max']} -> idle after {r['tasks_idle_after']}"
    )
    print(
        f"  sessions {r['sessions']} ({r['churn_leaves']} churn leaves), server accepted "
        f"{r['server_accepted_connections']}; connection losses {r['connection_losses']}, "
        f"failed {len(r['failed_players'])}, error messages {r['error_messages']}; "
        f"unexplained disconnects {r['unexplained_disconnects']}"
    )
    print(
        f"  poses received {r['poses_received']}, worst window delivery "
        f"{r['delivery_worst_window']:.1%}; tick p99 worst window "
        f"{r['tick_ms_p99_worst_window']} ms"
    )
    for name, ok in r["checks"].items():
        print(f"  {'ok ' if ok else 'FAIL'} {name}")
    for line in r["server_log_lines"]:
        print(f"  server log: {line[:200]}")


# --- command line --------------------------------------------------------------------------


def build_parser() -> argparse.ArgumentParser:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    sub = ap.add_subparsers(dest="mode", required=True)
    for name in ("ramp", "soak"):
        p = sub.add_parser(name)
        p.add_argument("--samples", type=int, default=100, help="server --samples N (100)")
        p.add_argument("--room-size", type=int, default=4, help="players per room (4)")
        p.add_argument("--join-timeout", type=float, default=60.0, help="seconds to join (60)")
        p.add_argument(
            "--server-arg",
            action="append",
            default=[],
            help="one more argument for posecast serve (repeatable)",
        )
        p.add_argument(
            "--server-cpus", type=parse_cpus, help="pin the server to these CPUs, e.g. 0"
        )
        p.add_argument(
            "--client-cpus", type=parse_cpus, help="pin the clients to these CPUs, e.g. 1"
        )
        p.add_argument(
            "--client-nice", type=int, default=0,
            help="run the clients this much nicer than the server, so that they yield to it (0)",
        )  # fmt: skip
        p.add_argument("--json", type=Path, help="also write the figures here")
    r = sub.choices["ramp"]
    r.add_argument(
        "--clients", choices=("lean", "sdk"), default="lean",
        help="lean: every player in one lean_clients.py process (pre-encoded frames, poses "
        "counted, not decoded); sdk: a posecast-sim process of SDK clients per step (lean)",
    )  # fmt: skip
    r.add_argument(
        "--protocol", type=int, choices=(1, 2), default=2,
        help="lean clients' wire protocol: 2, posecast.v2 pose records (what the SDKs speak); "
        "1, posecast.v1, one pose message per avatar per tick (2)",
    )  # fmt: skip
    r.add_argument("--step", type=int, default=4, help="players added per step (4)")
    r.add_argument("--max-players", type=int, default=256, help="stop before passing this")
    r.add_argument("--settle", type=float, default=3.0, help="seconds after joining (3)")
    r.add_argument("--window", type=float, default=10.0, help="measured seconds per step (10)")
    s = sub.choices["soak"]
    s.add_argument("--players", type=int, default=64, help="players at once (64)")
    s.add_argument("--seconds", type=float, default=600.0, help="measured seconds (600)")
    s.add_argument("--warmup", type=float, default=60.0, help="of which warm-up (60)")
    s.add_argument("--churn-every", type=float, default=3.0, help="one leave+join per S s (3)")
    s.add_argument("--procs", type=int, default=2, help="posecast-sim processes (2)")
    s.add_argument("--window", type=float, default=30.0, help="seconds per printed window (30)")
    s.add_argument("--sample-every", type=float, default=5.0, help="RSS/FD/task sampling (5)")
    s.add_argument(
        "--min-delivery",
        type=float,
        default=0.5,
        help="poses received / a full room's, every window after warm-up (0.5)",
    )
    s.add_argument("--max-rss-growth", type=float, default=5.0, help="percent (5)")
    s.add_argument("--fd-slack", type=int, default=4, help="FD spread allowed under load (4)")
    s.add_argument("--task-slack", type=int, default=8, help="task spread under load (8)")
    return ap


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    with tempfile.TemporaryDirectory(prefix="posecast-load-") as tmp:
        if args.mode == "ramp":
            report = ramp(args, Path(tmp))
            print(
                f"N={report['samples']}, rooms of {report['room_size']}, "
                f"{_clients(report)}: max sustainable "
                f"{report['max_sustainable_players']} players ({report['criteria']})"
            )
            ok = report["server_alive"]
        else:
            report = soak(args, Path(tmp))
            _print_soak_summary(report)
            ok = report["ok"]
    if args.json is not None:
        args.json.write_text(json.dumps(report, indent=1) + "\n", encoding="utf-8")
    return 0 if ok else 1


if __name__ == "__main__":
    raise SystemExit(main())
