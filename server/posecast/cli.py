"""The ``posecast`` command line. Configuration is parsed here, once, and passed down.

Subcommands:

* ``posecast data prepare --bvh DIR --out DIR`` - build a cached training dataset
* ``posecast serve [--dev] [--port N] ...`` - the pose-streaming server (``docs/server.md``)
* ``posecast token --room R --player P --role player`` - mint a development join token
* ``posecast demo`` - the data pipeline on a generated fixture (what ``make run`` does
  until the server lands)
"""

from __future__ import annotations

import argparse
import contextlib
import sys
from collections.abc import Sequence
from pathlib import Path

from posecast.errors import PosecastError


def _cmd_data_prepare(args: argparse.Namespace) -> int:
    from posecast.dataset.prepare import prepare
    from posecast.motion.rig import load_rigs

    rigs = load_rigs(args.rigs or ())
    report = prepare(
        args.bvh,
        args.out,
        rigs,
        rig_name=args.rig,
        skip_bad=args.skip_bad,
        split_file=args.split_file,
        progress=(lambda m: print(m, file=sys.stderr)) if args.verbose else None,
    )
    print(report.table())
    print(f"wrote {report.out_dir} in {report.seconds:.1f} s")
    return 0


def _cmd_demo(args: argparse.Namespace) -> int:
    import asyncio

    from posecast.demo import run

    with contextlib.suppress(KeyboardInterrupt):
        asyncio.run(run(args.port, args.seconds, args.bvh, args.samples))
    return 0


def _cmd_train(args: argparse.Namespace) -> int:
    import dataclasses

    torch_threads = args.threads
    if args.network in ("cvae", "ae"):
        from posecast.layout import Layout, spec
        from posecast.model.cvae import CVAEConfig
        from posecast.train.cvae_trainer import CVAETrainConfig, train_cvae

        det = args.network == "ae"
        if det and args.layout != Layout.HMD3_WAIST:
            raise SystemExit("the AE ablation exists for the 4-point layout only")
        ls = spec(args.layout)
        model_cfg = CVAEConfig(
            n_features=ls.n_features,
            deterministic=det,
            encoder_sees_pose=not det,
            layout=str(ls.layout),
            root_outputs=ls.root_outputs,
        )
        cfg = CVAETrainConfig(
            threads=torch_threads,
            seed=args.seed,
            rot_weight=args.rot_weight,
            no_orientation=args.no_orientation,
        )
        if args.steps:
            cfg = dataclasses.replace(cfg, steps=args.steps)
        path = train_cvae(args.data, args.out, model_cfg, cfg, resume=args.resume)
    else:
        from posecast.train.anomaly_trainer import AnomalyTrainConfig, train_anomaly

        acfg = AnomalyTrainConfig(threads=torch_threads, seed=args.seed)
        if args.steps:
            acfg = dataclasses.replace(acfg, steps=args.steps)
        path = train_anomaly(args.data, args.out, acfg, resume=args.resume)
    print(f"checkpoint: {path}")
    return 0


def _cmd_export(args: argparse.Namespace) -> int:
    from posecast.train.export import export_all, mean_pose_rot6d

    extra = {}
    if args.data is not None:
        extra["cvae_decoder"] = {"mean_pose_rot6d": mean_pose_rot6d(args.data)}
    for path in export_all(
        args.out, args.cvae, args.ae, args.anomaly, extra, cvae_hmd3=args.cvae_hmd3
    ):
        print(f"wrote {path}")
    return 0


def _cmd_eval(args: argparse.Namespace) -> int:
    import json

    from posecast.evaluation.runner import VARIANTS, evaluate, format_table

    if args.bvh is not None:
        from posecast.dataset.prepare import find_bvh_files, process_file
        from posecast.motion.rig import load_rigs

        rigs = load_rigs()
        clips = [process_file(p, rigs)[1] for p in find_bvh_files(args.bvh)]
        fps = 60.0
    else:
        from posecast.dataset.store import load_split

        split = load_split(args.data, args.split)
        clips = [split.clip(i) for i in range(split.n_clips)]
        fps = split.fps
    from posecast.engine.config import EngineConfig

    variants = args.variants.split(",") if args.variants else list(VARIANTS)
    if args.layout != "hmd3+waist" and not args.variants:
        variants.remove("ae_ik")  # the AE ablation is a 4-point model
    engine_cfg = EngineConfig(
        samples=args.samples,
        outlier_baseline=args.outlier_baseline,
        outlier_factor=args.outlier_factor,
    )
    report = evaluate(
        clips,
        fps,
        variants,
        args.models,
        log=lambda m: print(m, file=sys.stderr),
        engine_cfg=engine_cfg,
        layout=args.layout,
    )
    print(format_table(report))
    if args.json is not None:
        args.json.write_text(json.dumps(report, indent=1) + "\n", encoding="utf-8")
        print(f"wrote {args.json}")
    return 0


def _cmd_eval_apps(args: argparse.Namespace) -> int:
    import json

    from posecast.dataset.store import load_split
    from posecast.engine.anomaly import AnomalyScorer
    from posecast.evaluation.applications import table3
    from posecast.inference.artifact import load_artifact

    kick = None
    for split_name in ("train", "val", "test"):
        split = load_split(args.data, split_name)
        for i, meta in enumerate(split.clips):
            if meta["name"] == args.clip:
                kick = split.clip(i)
    if kick is None:
        print(f"posecast: clip {args.clip!r} is not in {args.data}", file=sys.stderr)
        return 2
    dec = load_artifact("cvae_decoder", args.models, threads=args.threads)
    scorer = AnomalyScorer(load_artifact("anomaly", args.models, threads=args.threads))
    counts = [int(c) for c in args.samples.split(",")]
    report = table3(dec, scorer, kick, sample_counts=counts, runs=args.runs)
    report["clip"] = args.clip
    print(json.dumps(report, indent=1))
    if args.json is not None:
        args.json.write_text(json.dumps(report, indent=1) + "\n", encoding="utf-8")
    return 0


def _cmd_bench_engine(args: argparse.Namespace) -> int:
    import json

    from posecast.bench.engine_bench import run

    counts = [int(p) for p in args.players.split(",")]
    report = run(
        counts, args.samples, args.threads, args.ticks, args.naive_players, args.hmd3_share
    )
    print(f"{'players':>8s} {'p50 ms':>8s} {'p99 ms':>8s} {'GFLOP/s':>8s} {'MB/player':>10s}")
    for i, p in enumerate(report["players"]):
        print(
            f"{p:8d} {report['tick_p50_ms'][i]:8.2f} {report['tick_p99_ms'][i]:8.2f} "
            f"{report['gflops'][i]:8.1f} {report['rss_mb_per_player'][i]:10.2f}"
        )
    print(
        f"max players at 60 Hz (p99 < 16.7 ms), N={args.samples}: {report['max_realtime_players']}"
    )
    print(f"peak: {report['peak_gflops']} GFLOP/s; naive loop: {report['naive_loop']}")
    both = report.get("both_models")
    if both:
        print(f"both models loaded, {both['hmd3_share']:.0%} of the players headset-only:")
        print(f"{'players':>8s} {'hmd3':>5s} {'p50 ms':>8s} {'p99 ms':>8s} {'MB/player':>10s}")
        for i, p in enumerate(report["players"]):
            print(
                f"{p:8d} {both['hmd3_players'][i]:5d} {both['tick_p50_ms'][i]:8.2f} "
                f"{both['tick_p99_ms'][i]:8.2f} {both['rss_mb_per_player'][i]:10.2f}"
            )
        print(f"max players at 60 Hz, both models: {both['max_realtime_players']}")
    if args.json is not None:
        args.json.write_text(json.dumps(report, indent=1) + "\n", encoding="utf-8")
    return 0


def _cmd_serve(args: argparse.Namespace) -> int:
    import asyncio
    import os

    from posecast.service.app import serve_until_signal
    from posecast.service.config import ServerConfig
    from posecast.service.logging import configure

    overrides = {k: v for k, v in vars(args).items() if k not in ("command", "func")}
    cfg = ServerConfig.from_sources(os.environ, overrides)
    configure(cfg.log_level)
    if cfg.dev and not os.environ.get("POSECAST_TOKEN_SECRET"):
        print(f"posecast: --dev: token secret for this run: {cfg.token_secret}", flush=True)

    def ready(port: int) -> None:
        print(f"posecast: listening on ws://{cfg.host}:{port}", flush=True)

    asyncio.run(serve_until_signal(cfg, ready))
    return 0


def _cmd_token(args: argparse.Namespace) -> int:
    import os
    import time

    from posecast.auth.tokens import mint

    secret = args.secret or os.environ.get("POSECAST_TOKEN_SECRET", "")
    if not secret:
        print("posecast: token: pass --secret or set POSECAST_TOKEN_SECRET", file=sys.stderr)
        return 2
    rooms = tuple(r for r in (args.rooms or "").split(",") if r)
    print(
        mint(
            secret.encode("utf-8"),
            room=args.room,
            player=args.player,
            role=args.role,
            ttl_s=args.ttl,
            now=time.time(),
            rooms=rooms,
        )
    )
    return 0


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="posecast", description=__doc__.splitlines()[0])
    sub = parser.add_subparsers(dest="command", required=True)

    data = sub.add_parser("data", help="motion data tools")
    data_sub = data.add_subparsers(dest="data_command", required=True)
    prep = data_sub.add_parser("prepare", help="BVH tree -> cached canonical dataset")
    prep.add_argument("--bvh", required=True, type=Path, help="directory of .bvh / .bvh.gz files")
    prep.add_argument("--out", required=True, type=Path, help="output directory")
    prep.add_argument("--skip-bad", action="store_true", help="skip and list unreadable files")
    prep.add_argument("--rig", default=None, help="force one rig instead of auto-detecting")
    prep.add_argument(
        "--rigs", action="append", type=Path, help="extra directory of rig *.json maps"
    )
    prep.add_argument("--split-file", type=Path, default=None, help="subject split table")
    prep.add_argument("-v", "--verbose", action="store_true", help="log every file")
    prep.set_defaults(func=_cmd_data_prepare)

    train = sub.add_parser("train", help="train a network (needs posecast[train])")
    train.add_argument("network", choices=("cvae", "ae", "anomaly"))
    train.add_argument("--data", required=True, type=Path, help="prepared dataset directory")
    train.add_argument("--out", required=True, type=Path, help="run directory (checkpoint.pt)")
    train.add_argument("--steps", type=int, default=0, help="iterations (0: the default)")
    train.add_argument("--resume", action="store_true", help="continue from out/checkpoint.pt")
    train.add_argument("--threads", type=int, default=2, help="torch CPU threads (default 2)")
    train.add_argument("--seed", type=int, default=0)
    train.add_argument(
        "--rot-weight",
        type=float,
        default=0.0,
        help="weight of the local-rotation loss (0: positions only, as the shipped 4-point "
        "model; the headset-only model uses 10)",
    )
    train.add_argument(
        "--layout",
        default="hmd3+waist",
        choices=("hmd3+waist", "hmd3"),
        help="tracker layout the CVAE serves (default hmd3+waist)",
    )
    train.add_argument(
        "--no-orientation",
        action="store_true",
        help="ablation: zero the hmd3 model's orientation inputs",
    )
    train.set_defaults(func=_cmd_train)

    export = sub.add_parser("export", help="checkpoints -> ONNX + JSON sidecars")
    export.add_argument("--out", type=Path, required=True, help="models directory")
    export.add_argument("--cvae", type=Path, help="CVAE checkpoint")
    export.add_argument("--cvae-hmd3", type=Path, help="headset-only (hmd3) CVAE checkpoint")
    export.add_argument("--ae", type=Path, help="deterministic AE checkpoint")
    export.add_argument("--anomaly", type=Path, help="anomaly AE checkpoint")
    export.add_argument("--data", type=Path, help="prepared dataset (for the mean pose)")
    export.set_defaults(func=_cmd_export)

    ev = sub.add_parser("eval", help="evaluate the shipped models")
    src = ev.add_mutually_exclusive_group(required=True)
    src.add_argument("--bvh", type=Path, help="evaluate every BVH under this directory")
    src.add_argument("--data", type=Path, help="prepared dataset directory")
    ev.add_argument("--split", default="test", help="split of --data (default: test)")
    ev.add_argument("--json", type=Path, help="write the report here")
    ev.add_argument("--models", type=Path, help="models directory (default: shipped)")
    ev.add_argument("--variants", help="comma-separated subset of variants")
    ev.add_argument(
        "--layout",
        default="hmd3+waist",
        choices=("hmd3+waist", "hmd3"),
        help="tracker layout, i.e. which model (default hmd3+waist)",
    )
    ev.add_argument("--samples", type=int, default=100, help="SSI latent samples N (100)")
    ev.add_argument("--outlier-factor", type=float, default=2.0, help="SSI outlier factor (2)")
    ev.add_argument(
        "--outlier-baseline",
        default="zero",
        choices=("min", "zero"),
        help="SSI outlier rule: R_c > 2r (zero, the paper; default) or R_c - min R > 2r (min)",
    )
    ev.set_defaults(func=_cmd_eval)

    apps = sub.add_parser("eval-apps", help="Table 3: target hitting and collision avoidance")
    apps.add_argument("--data", type=Path, required=True, help="prepared dataset directory")
    apps.add_argument("--clip", default="135_04", help="kick clip name (default: 135_04)")
    apps.add_argument("--samples", default="1,10,100,1000", help="sample counts")
    apps.add_argument("--runs", type=int, default=100, help="runs (seeds) per setting")
    apps.add_argument("--models", type=Path, help="models directory (default: shipped)")
    apps.add_argument("--threads", type=int, default=2)
    apps.add_argument("--json", type=Path, help="write the report here")
    apps.set_defaults(func=_cmd_eval_apps)

    bench = sub.add_parser("bench", help="benchmarks")
    bench_sub = bench.add_subparsers(dest="bench_command", required=True)
    be = bench_sub.add_parser("engine", help="per-tick cost of the SSI engine")
    be.add_argument("--players", default="1,10,50,100,200", help="player counts")
    be.add_argument("--samples", type=int, default=100, help="latent samples N")
    be.add_argument("--threads", type=int, default=2, help="ONNX Runtime intra-op threads")
    be.add_argument("--ticks", type=int, default=120, help="measured ticks per count")
    be.add_argument("--naive-players", type=int, default=10, help="players for the naive loop")
    be.add_argument(
        "--hmd3-share",
        type=float,
        default=0.5,
        help="also load the headset-only model and run this share of players on it "
        "(default 0.5; 0: the 4-point model only)",
    )
    be.add_argument("--json", type=Path, help="write the report here")
    be.set_defaults(func=_cmd_bench_engine)

    from posecast.service.config import add_arguments

    serve = sub.add_parser("serve", help="run the pose-streaming server (docs/server.md)")
    add_arguments(serve)
    serve.set_defaults(func=_cmd_serve)

    tok = sub.add_parser("token", help="mint a join token (development; the backend mints)")
    tok.add_argument("--secret", help="HMAC key (default: $POSECAST_TOKEN_SECRET)")
    tok.add_argument("--room", required=True, help="room the token joins")
    tok.add_argument("--player", required=True, help="player id (server-unique)")
    tok.add_argument("--role", default="player", choices=("player", "spectator", "backend"))
    tok.add_argument("--rooms", help="comma-separated extra rooms a backend may watch")
    tok.add_argument("--ttl", type=int, default=3600, help="seconds until it expires (3600)")
    tok.set_defaults(func=_cmd_token)

    demo = sub.add_parser("demo", help="server + two simulated headsets + a spectator (make run)")
    demo.add_argument("--port", type=int, default=8765, help="port (0: any free one)")
    demo.add_argument("--seconds", type=float, default=None, help="stop after this long")
    demo.add_argument("--bvh", type=Path, default=None, help="replay this BVH file")
    demo.add_argument("--samples", type=int, default=100, help="latent samples N")
    demo.set_defaults(func=_cmd_demo)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    try:
        return int(args.func(args))
    except PosecastError as exc:
        print(f"posecast: error [{exc.code}]: {exc}", file=sys.stderr)
        return 2


if __name__ == "__main__":  # pragma: no cover
    raise SystemExit(main())
