"""``posecast bench latency``: capture to display with real SDK clients on loopback
against a real ``posecast serve``, split into look-ahead, server queue and tick,
transport and client buffer (:mod:`posecast.offline.evaluation.latency`,
``docs/latency-benchmark.md``)."""

from __future__ import annotations

import argparse
from dataclasses import fields
from pathlib import Path
from typing import Any

from posecast.cli.common import (
    add_defaulted,
    at_least,
    check_json_out,
    check_samples,
    config_error,
    finite,
    given,
)

CMD = "bench latency"
ROWS = (
    ("capture to display", None),
    ("  look-ahead", "lookahead"),
    ("  server queue+tick", "server_queue_tick"),
    ("  transport", "transport"),
    ("  client buffer", "client_buffer"),
)


def cmd_bench_latency(args: argparse.Namespace) -> int:
    import importlib.util
    import json

    from posecast.online.protocol.messages import MAX_LOOKAHEAD_FRAMES

    at_least("--players", args.players, 2, CMD)
    at_least("--room-size", args.room_size, 2, CMD)
    at_least("--procs", args.procs, 1, CMD)
    finite("--seconds", args.seconds, CMD, positive=True)
    finite("--warmup", args.warmup, CMD)
    finite("--display-hz", args.display_hz, CMD, positive=True)
    finite("--jitter-ms", args.jitter_ms, CMD)
    finite("--down-jitter-ms", args.down_jitter_ms, CMD)
    if args.samples is not None:
        check_samples("--samples", [args.samples], CMD)
    if args.frame_queue is not None:
        at_least("--frame-queue", args.frame_queue, 1, CMD)
    if args.lookahead is not None and not 0 <= args.lookahead <= MAX_LOOKAHEAD_FRAMES:
        raise config_error(
            f"--lookahead {args.lookahead} outside [0, {MAX_LOOKAHEAD_FRAMES}]",
            "frames the engine holds a pose back; leave it out for the server's default",
        )
    if not 0.0 <= args.drop < 1.0:
        raise config_error(
            f"--drop {args.drop} outside [0, 1)", "the share of frames the relay loses, e.g. 0.2"
        )
    if importlib.util.find_spec("posecast_client") is None:
        raise config_error(
            "this benchmark runs the Python SDK (posecast_client), which is not installed",
            "pip install -e client_sdk/python (make run and make test install it)",
        )
    if args.sdk == "typescript":
        from posecast.offline.evaluation.latency.node_players import NPM_HINT, node_missing

        missing = node_missing()
        if missing is not None:
            raise config_error(f"--sdk typescript: {missing}", NPM_HINT)
    check_json_out(args.json)
    from posecast.offline.evaluation.latency.run import LatencyConfig, Sdk, run_latency

    # The flags named as the config's fields pass as they are; four are converted.
    cfg = LatencyConfig(
        **given(args, (f.name for f in fields(LatencyConfig) if f.name != "sdk")),
        sdk=Sdk(args.sdk),
        warmup_s=args.warmup,
        jitter_s=args.jitter_ms / 1000.0,
        down_jitter_s=args.down_jitter_ms / 1000.0,
    )
    report = run_latency(cfg)
    print_report(report)
    if args.json is not None:
        args.json.write_text(json.dumps(report, indent=1) + "\n", encoding="utf-8")
    return 0


def _cells(phase: dict[str, Any], key: str | None) -> str:
    if key is None:
        p50, p99 = phase["capture_to_display_ms_p50"], phase["capture_to_display_ms_p99"]
        mean = phase["capture_to_display_ms_mean"]
    else:
        c = phase["components_ms"][key]
        p50, p99, mean = c["p50"], c["p99"], c["mean"]
    return "".join(" " + (f"{v:8.1f}" if v is not None else f"{'-':>8s}") for v in (p50, p99, mean))


def print_report(report: dict[str, Any]) -> None:
    """The figures of a ``bench latency`` report as a table, a column group per phase."""
    cfg = report["config"]
    phases = [("clean", report)] + ([("lossy", report["lossy"])] if "lossy" in report else [])
    print(
        f"capture to display: {cfg['players']} players in rooms of {cfg['room_size']}, "
        f"{report['rate_hz']:g} Hz frames, {cfg['display_hz']:g} Hz display, "
        f"posecast.v{report['protocol']}, look-ahead {report['lookahead_frames']} frames, "
        f"{cfg['seconds']:g} s measured"
    )
    head = "".join(f" {n + ' p50':>8s} {n + ' p99':>8s} {n + ' mean':>8s}"
                   for n, _ in phases)  # fmt: skip
    print(f"{'ms':20s}{head}")
    for label, key in ROWS:
        print(f"{label:20s}" + "".join(_cells(phase, key) for _, phase in phases))
    for name, phase in phases:
        late = 100 * (phase["display_frames_late_share"] or 0)
        print(
            f"{name}: {phase['poses_displayed']} poses displayed of {phase['poses_expected']} "
            f"expected; max joint jump at {cfg['display_hz']:g} Hz {phase['max_joint_jump_cm']} cm "
            f"(p99 {phase['p99_joint_jump_cm']} cm); tick {phase['tick_ms_mean']} ms mean, "
            f"{phase['tick_overruns']:g} overruns; frames held a tick in their queue "
            f"{100 * (phase['queue_held_share'] or 0):.1f} %; server "
            f"{phase['server_cpu_cores']} cores, clients {phase['clients_cpu_cores']} cores of "
            f"{report['machine_cores']}; display frames late {late:.1f} %"
        )
        if phase["failures"] or phase["errors"]:
            print(f"{name}: errors {phase['errors']}, failures {phase['failures']}")
        if _starved(phase):
            print(
                f"{name}: WARNING the machine was too busy for these figures to be the "
                "stream's (tick overruns, or over 5 % of display frames late): run on a "
                "quiet machine"
            )
    lossy = report.get("lossy")
    if lossy:
        relay = lossy["relay"]
        print(
            f"lossy relay: {relay['frames_dropped']} of {relay['frames_in']} frames dropped, "
            f"{relay['frames_reordered']} overtaken, 0-{relay['jitter_ms']:g} ms uplink and "
            f"0-{relay['down_jitter_ms']:g} ms downlink jitter; "
            f"p99 {_x(lossy['p99_vs_clean'])} clean, max joint jump "
            f"{_x(lossy['max_joint_jump_vs_clean'])} clean"
        )


def _x(ratio: float | None) -> str:
    return "-" if ratio is None else f"{ratio:.2f}x"


def _starved(phase: dict[str, Any]) -> bool:
    """Whether the machine held up the server or the clients (then the figures are the
    machine's more than the stream's)."""
    return bool(phase["tick_overruns"] > 0 or (phase["display_frames_late_share"] or 0) > 0.05)


def add_parser(bench_sub: argparse._SubParsersAction[Any]) -> None:
    """Add ``posecast bench latency`` to ``bench_sub`` (``posecast bench``'s commands)."""
    bl = bench_sub.add_parser(
        "latency",
        help="capture-to-display latency with SDK clients on loopback",
        description="SDK players (Python, or TypeScript in Node) on loopback against a real "
        "posecast serve, 60 Hz frames of a generated walk, every room-mate's pose shown "
        "through the SDK's interpolator at 90 Hz: capture to first display, p50 and p99, "
        "split into look-ahead, server queue and tick, transport and client buffer.",
    )
    bl.add_argument(
        "--sdk",
        choices=("python", "typescript"),  # run.Sdk's values (not imported to build the parser)
        default="python",
        help="the players' SDK: the Python SDK in Python client processes, or the TypeScript "
        "SDK in Node processes (needs node and `npm ci` in client_sdk/typescript) "
        "(default %(default)s)",
    )
    add_defaulted(bl, "--players", 16, "players")
    add_defaulted(bl, "--room-size", 8, "players per room")
    add_defaulted(bl, "--seconds", 10.0, "measured seconds")
    add_defaulted(bl, "--warmup", 3.0, "seconds of streaming before the measured window")
    add_defaulted(bl, "--display-hz", 90.0, "each receiver's display rate")
    add_defaulted(bl, "--procs", 2, "client processes the players are dealt over")
    bl.add_argument(
        "--draw-all",
        action="store_true",
        help="every player samples its room-mates' poses each display frame (default: one "
        "per room in each client process; the others follow the times their "
        "interpolators would show)",
    )
    bl.add_argument(
        "--samples", type=int, help="the server's latent samples N (default: the server's)"
    )
    bl.add_argument(
        "--lookahead", type=int, help="the server's look-ahead in frames (default: the server's)"
    )
    bl.add_argument(
        "--frame-queue",
        type=int,
        help="the server's frames kept per player between ticks (default: the server's)",
    )
    bl.add_argument(
        "--delayed-emission",
        action="store_true",
        help="the server emits frame n - tau at tick n, the paper's setting (with --lookahead 10)",
    )
    bl.add_argument(
        "--lossy",
        action="store_true",
        help="then run again with every player behind the reliability suite's lossy relay",
    )
    relay = (  # the lossy relay's settings: flag, default, help, help after the default
        ("--drop", 0.2, "the share of frames the relay loses", ""),
        ("--jitter-ms", 40.0, "each message up held uniform(0, this) ms", ""),
        (
            "--down-jitter-ms",
            0.0,
            "each message down held uniform(0, this) ms, in order",
            ", as the reliability suite's relay",
        ),
    )
    for flag, default, text, more in relay:
        add_defaulted(bl, flag, default, "--lossy: " + text, more)
    bl.add_argument("--json", type=Path, help="write the report here")
    bl.set_defaults(func=cmd_bench_latency)
