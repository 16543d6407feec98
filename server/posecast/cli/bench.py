"""``posecast bench engine``: the per-tick cost of the SSI engine at each player count
(:mod:`posecast.offline.evaluation.engine_speed`, ``docs/engine.md``); ``posecast bench
latency`` is :mod:`posecast.cli.bench_latency`."""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any

from posecast.cli import bench_latency
from posecast.cli.common import (
    add_defaulted,
    at_least,
    backend_names,
    check_json_out,
    check_samples,
    config_error,
    int_list,
)


def cmd_bench_engine(args: argparse.Namespace) -> int:
    import json

    cmd = "bench engine"
    counts = int_list("--players", args.players, cmd)
    check_samples("--samples", [args.samples], cmd)
    for option, value in (
        ("--threads", args.threads),
        ("--ticks", args.ticks),
        ("--naive-players", args.naive_players),
    ):
        at_least(option, value, 1, cmd)
    if not 0.0 <= args.hmd3_share <= 1.0:
        raise config_error(
            f"--hmd3-share {args.hmd3_share} outside [0, 1]",
            "the share of players on the headset-only model, e.g. 0.5 (0: none)",
        )
    backends = backend_names("--backend", args.backend, cmd, many=True)
    check_json_out(args.json)
    from posecast.offline.evaluation.engine_speed import run_side_by_side

    reports = run_side_by_side(
        list(backends),
        counts,
        args.samples,
        args.threads,
        args.ticks,
        args.naive_players,
        args.hmd3_share,
        args.sets,
    )
    for report in reports:
        _print_bench(report, args.samples)
    if len(reports) > 1:
        _print_ratios(reports)
    if args.json is not None:
        out = reports[0] if len(reports) == 1 else reports
        args.json.write_text(json.dumps(out, indent=1) + "\n", encoding="utf-8")
    return 0


def _print_ratios(reports: list[dict[str, Any]]) -> None:
    """p50 and p99 of every backend per player count, and each one's speed-up over
    the last (measured side by side, count by count)."""
    names = [r["backend"] for r in reports]
    ref = reports[-1]
    print(f"side by side (speed-up over {names[-1]}, p50):")
    head = "".join(f" {n + ' p50':>12s} {n + ' p99':>12s}" for n in names)
    print(f"{'players':>8s}{head} {'speed-up':>9s}")
    for i, p in enumerate(ref["players"]):
        cells = "".join(
            f" {r['tick_p50_ms'][i]:12.2f} {r['tick_p99_ms'][i]:12.2f}" for r in reports
        )
        ratio = ref["tick_p50_ms"][i] / max(reports[0]["tick_p50_ms"][i], 1e-9)
        print(f"{p:8d}{cells} {ratio:8.2f}x")


def _table(
    players: list[int],
    src: dict[str, Any],
    before: tuple[tuple[str, str, str], ...] = (),
    after: tuple[tuple[str, str, str], ...] = (),
) -> None:
    """One table of ``posecast bench engine``: a row per player count with the p50 and
    p99 tick and the memory per player from ``src``, and the columns ``before`` and
    ``after`` them, each a (heading, format spec, key of ``src``): the heading is
    right-aligned to the spec's width."""
    cols = [
        ("players", "8d", players),
        *((head, spec, src[key]) for head, spec, key in before),
        ("p50 ms", "8.2f", src["tick_p50_ms"]),
        ("p99 ms", "8.2f", src["tick_p99_ms"]),
        *((head, spec, src[key]) for head, spec, key in after),
        ("MB/player", "10.2f", src["rss_mb_per_player"]),
    ]
    print(" ".join(f"{head:>{spec.split('.')[0].rstrip('d')}s}" for head, spec, _ in cols))
    for i in range(len(players)):
        print(" ".join(f"{values[i]:{spec}}" for _, spec, values in cols))


def _print_bench(report: dict[str, Any], samples: int) -> None:
    """One backend's tables of ``posecast bench engine``."""
    from posecast.offline.evaluation.engine_speed import realtime_summary

    used, asked = report["backend"], report["backend_asked"]
    print(f"backend {used}" + (f" ({asked} asked for; unavailable)" if used != asked else ""))
    _table(report["players"], report, after=(("GFLOP/s", "8.1f", "gflops"),))
    fit = realtime_summary(report["players"], report["tick_p99_ms"])
    print(f"max players at 60 Hz (p99 < 16.7 ms), N={samples}: {fit}")
    if report["native_isa"]:
        print(f"native kernels: {report['native_isa']}, precision {report['precision']}")
    print(f"naive loop: {report['naive_loop']}")
    both = report.get("both_models")
    if both:
        print(
            f"both models loaded (backend {both['backend']}), {both['hmd3_share']:.0%} of the "
            "players headset-only:"
        )
        _table(report["players"], both, before=(("hmd3", "5d", "hmd3_players"),))
        fit = realtime_summary(report["players"], both["tick_p99_ms"])
        print(f"max players at 60 Hz, both models: {fit}")
    sets = report.get("mixed_sets")
    if sets:
        print(
            f"mixed tracker sets on the sites model (backend {sets['backend']}), players on "
            f"{', '.join(sets['sets'])} in turn, beside hmd3+waist (p50 ratio):"
        )
        _table(report["players"], sets, after=(("ratio", "6.2f", "p50_ratio"),))
        fit = realtime_summary(report["players"], sets["tick_p99_ms"])
        print(f"max players at 60 Hz, mixed sets: {fit}")


def add_parsers(sub: argparse._SubParsersAction[Any]) -> None:
    """Add ``posecast bench engine`` and ``bench latency`` to ``sub`` (``posecast``'s
    commands)."""
    bench = sub.add_parser("bench", help="benchmarks")
    bench_sub = bench.add_subparsers(dest="bench_command", required=True)
    be = bench_sub.add_parser(
        "engine",
        help="per-tick cost of the SSI engine",
        description="The engine's whole per-tick cost at each player count, and how many "
        "players hold 60 Hz (p99 tick under 16.7 ms) as far as the counts tested tell.",
    )
    add_defaulted(
        be, "--players", "1,10,50,100,200", "player counts, comma-separated, each measured in turn"
    )
    add_defaulted(be, "--samples", 100, "latent samples N")
    add_defaulted(be, "--threads", 2, "the backend's intra-op threads")
    be.add_argument(
        "--backend",
        default="native",
        help="inference backend, or a comma-separated list to run each in turn, one table "
        "each (native, onnx, torch; default native, which falls back to onnx where the "
        "extension does not load; --json then writes a list)",
    )
    add_defaulted(be, "--ticks", 120, "measured ticks per count")
    add_defaulted(be, "--naive-players", 10, "players for the per-player loop it is compared with")
    add_defaulted(
        be,
        "--hmd3-share",
        0.5,
        "also load the headset-only model and run this share of players on it",
        "; 0: the 4-point model only",
    )
    be.add_argument(
        "--sets",
        action="store_true",
        help="also run every player on the one model of every tracker set, the six sets of "
        "the evaluation table in turn, beside the 4-point figure count by count",
    )
    be.add_argument("--json", type=Path, help="write the report here")
    be.set_defaults(func=cmd_bench_engine)
    bench_latency.add_parser(bench_sub)
