"""The ``posecast`` command line. Configuration is parsed here, once, and passed down.

Subcommands:

* ``posecast data prepare --bvh DIR --out DIR`` - build a cached training dataset
* ``posecast demo`` - the data pipeline on a generated fixture (what ``make run`` does
  until the server lands)
"""

from __future__ import annotations

import argparse
import sys
import tempfile
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
    from posecast.dataset.prepare import prepare
    from posecast.motion.rig import load_rigs
    from posecast.motion.synthetic import walk_clip, write_fixture_bvh

    with tempfile.TemporaryDirectory() as tmp:
        root = Path(tmp) / "bvh"
        for i, layout in enumerate(("cmu_mb", "cmu_daz", "cmu_mb", "cmu_daz")):
            folder = root / layout / f"9{i}"
            folder.mkdir(parents=True)
            clip = walk_clip(seconds=6.0, fps=120.0, seed=i)
            write_fixture_bvh(folder / f"9{i}_01.bvh.gz", clip, layout)
        print(f"generated 4 procedural BVH clips under {root}")
        report = prepare(root, Path(tmp) / "prepared", load_rigs())
        print(report.table())
    print("posecast demo: data pipeline OK (the server, viewer and simulated player come next)")
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

    demo = sub.add_parser("demo", help="run the bundled demo")
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
