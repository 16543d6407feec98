"""What ``load.py`` prints: the ramp's table and verdict, the soak's windows and
summary, and the pinning both record in their JSON."""

from __future__ import annotations

import argparse
from typing import Any


def pinning(args: argparse.Namespace) -> dict[str, Any]:
    return {
        "server_cpus": sorted(args.server_cpus or []) or "any",
        "client_cpus": sorted(args.client_cpus or []) or "any",
        "client_nice": args.client_nice,
        "server_args": args.server_arg,
    }


def print_ramp_row(row: dict[str, Any], header: bool) -> None:
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


def print_ramp_summary(report: dict[str, Any]) -> None:
    print(
        f"N={report['samples']}, rooms of {report['room_size']}, "
        f"{_clients(report)}: max sustainable "
        f"{report['max_sustainable_players']} players ({report['criteria']})"
    )


def _clients(report: dict[str, Any]) -> str:
    if report["clients"] == "lean":
        return f"lean clients (posecast.v{report['protocol']})"
    return f"{report['clients']} clients"


def print_soak_window(w: dict[str, Any], header: bool) -> None:
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


def print_soak_summary(r: dict[str, Any]) -> None:
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
