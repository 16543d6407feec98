"""``posecast data prepare|clearance|wrists``: motion data tools. ``prepare`` turns
BVH and ASF/AMC trees into the cached training dataset
(:mod:`posecast.offline.dataset.prepare`, ``docs/data.md``); ``clearance`` and
``wrists`` measure a prepared split for the engine's swing-clearance table and elbow
hint."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import Any

from posecast.cli.common import (
    check_out_dir,
    config_error,
    dataset_split,
    finite,
    hinted,
    need,
)
from posecast.errors import RigError


def cmd_data_prepare(args: argparse.Namespace) -> int:
    if not (args.bvh or args.amc or args.hdm05):
        raise config_error(
            "no motion to prepare",
            "pass --bvh DIR (BVH files), --amc DIR (ASF/AMC files) and/or --hdm05 DIR "
            "(the HDM05 set, CC BY-SA 3.0), each as often as needed",
        )
    finite("--amc-fps", args.amc_fps, "data prepare", positive=True)
    check_out_dir("--out", args.out)
    for d in args.rigs or ():
        if not d.is_dir():
            raise config_error(
                f"--rigs {d}: no such directory", "pass a directory of rig *.json maps"
            )
    need("data", "scipy")
    from posecast.offline.dataset.prepare import prepare
    from posecast.offline.motion.rig import load_rigs

    rigs = load_rigs(args.rigs or ())
    names = [r.name for r in rigs]
    if args.rig is not None and args.rig not in names:
        raise hinted(
            RigError(f"unknown rig {args.rig!r}; known: {', '.join(names)}"),
            "pick one of those names, or add its map with --rigs DIR (docs/data.md)",
        )
    report = prepare(
        args.bvh,
        args.out,
        rigs,
        amc_roots=args.amc,
        hdm05_roots=args.hdm05,
        amc_fps=args.amc_fps,
        rig_name=args.rig,
        skip_bad=args.skip_bad,
        split_file=args.split_file,
        progress=(lambda m: print(m, file=sys.stderr)) if args.verbose else None,
    )
    print(report.table())
    print(f"wrote {report.out_dir} in {report.seconds:.1f} s")
    return 0


def cmd_data_clearance(args: argparse.Namespace) -> int:
    from posecast.offline.dataset.split import SPLITS

    if args.split not in SPLITS:
        raise config_error(f"--split {args.split!r} unknown", f"use one of {', '.join(SPLITS)}")
    finite("--percentile", args.percentile, "data clearance")
    if not 0.0 <= args.percentile <= 100.0:
        raise config_error("--percentile must be within 0 to 100", "for example --percentile 5")
    from posecast.offline.dataset.clearance import clearance_table
    from posecast.offline.evaluation.reconstruct import clip_truth

    split = dataset_split(args.data, args.split, "measure")
    clips = (clip_truth(split.clip(i))[1] for i in range(split.n_clips))
    centres, heights, counts = clearance_table(clips, split.fps, args.percentile)
    print(f"toe height, percentile {args.percentile:g}, {args.split} split ground truth")
    print("speed_m_s  toe_frames  clearance_m")
    for c, n, h in zip(centres, counts, heights, strict=True):
        print(f"{c:9.3f}  {n:10d}  {h:11.3f}")
    print(f"SPEEDS_M_S = {centres}")
    print(f"CLEARANCE_M = {heights}")
    return 0


def cmd_data_wrists(args: argparse.Namespace) -> int:
    from posecast.offline.dataset.split import SPLITS

    if args.split not in SPLITS:
        raise config_error(f"--split {args.split!r} unknown", f"use one of {', '.join(SPLITS)}")
    from posecast.offline.dataset.wrists import bend_summary
    from posecast.offline.evaluation.reconstruct import clip_truth

    split = dataset_split(args.data, args.split, "measure")
    stats = bend_summary(clip_truth(split.clip(i)) for i in range(split.n_clips))
    print(f"wrist bend (forearm against a straight wrist), {args.split} split ground truth")
    for key, value in stats.items():
        print(f"{key:12s} {value:10.1f}")
    return 0


def add_parsers(sub: argparse._SubParsersAction[Any]) -> None:
    """Add ``posecast data prepare|clearance|wrists`` to ``sub`` (``posecast``'s commands)."""
    data = sub.add_parser("data", help="motion data tools")
    data_sub = data.add_subparsers(dest="data_command", required=True)
    prep = data_sub.add_parser("prepare", help="BVH and ASF/AMC trees -> cached canonical dataset")
    prep.add_argument(
        "--bvh", action="append", type=Path, help="directory of .bvh / .bvh.gz files (repeatable)"
    )
    prep.add_argument(
        "--amc",
        action="append",
        type=Path,
        help="directory of .amc / .amc.gz files, each with its subject's .asf/.asx "
        "in the same folder (repeatable)",
    )
    prep.add_argument(
        "--hdm05",
        action="append",
        type=Path,
        help="directory of HDM05 ASF/AMC files: opt-in, CC BY-SA 3.0, recorded in the "
        "manifest (repeatable)",
    )
    prep.add_argument(
        "--amc-fps",
        type=float,
        default=120.0,
        help="frame rate of AMC files, which store none (default 120; HDM05 names say theirs)",
    )
    prep.add_argument("--out", required=True, type=Path, help="output directory")
    prep.add_argument("--skip-bad", action="store_true", help="skip and list unreadable files")
    prep.add_argument("--rig", default=None, help="force one rig instead of auto-detecting")
    prep.add_argument(
        "--rigs", action="append", type=Path, help="extra directory of rig *.json maps"
    )
    prep.add_argument("--split-file", type=Path, default=None, help="subject split table")
    prep.add_argument("-v", "--verbose", action="store_true", help="log every file")
    prep.set_defaults(func=cmd_data_prepare)

    clear = data_sub.add_parser(
        "clearance", help="how high real toes keep off the floor at each speed (the engine's table)"
    )
    clear.add_argument("--data", required=True, type=Path, help="prepared dataset directory")
    clear.add_argument("--split", default="train", help="split to measure (default train)")
    clear.add_argument(
        "--percentile", type=float, default=5.0, help="height percentile per speed (default 5)"
    )
    clear.set_defaults(func=cmd_data_clearance)

    wrists = data_sub.add_parser(
        "wrists", help="how far real wrists bend (behind the engine's elbow hint)"
    )
    wrists.add_argument("--data", required=True, type=Path, help="prepared dataset directory")
    wrists.add_argument("--split", default="val", help="split to measure (default val)")
    wrists.set_defaults(func=cmd_data_wrists)
