"""The ``posecast`` command line. Configuration is parsed here, once, and passed down.

Subcommands (each a thin edge over the module named):

* ``posecast data prepare [--bvh DIR ...] [--amc DIR ...] [--hdm05 DIR ...] --out DIR`` -
  BVH and ASF/AMC trees -> cached training dataset
  (:mod:`posecast.offline.dataset.prepare`, ``docs/data.md``)
* ``posecast train cvae|ae|anomaly --data DIR --out DIR`` - train a network
  (:mod:`posecast.offline.train.cvae_trainer`, :mod:`posecast.offline.train.anomaly_trainer`;
  needs ``posecast[train]``)
* ``posecast export --out DIR [--cvae|--cvae-hmd3|--cvae-sites|--ae|--anomaly CKPT]`` -
  checkpoints -> ONNX models and JSON sidecars (:mod:`posecast.offline.train.export`)
* ``posecast eval --data DIR | --bvh DIR`` - evaluate the models
  (:mod:`posecast.offline.evaluation.runner`, ``docs/evaluation.md``)
* ``posecast eval-apps --data DIR`` - Table 3: target hitting and collision avoidance
  (:mod:`posecast.offline.evaluation.applications`)
* ``posecast bench engine`` - per-tick cost of the SSI engine
  (:mod:`posecast.offline.evaluation.engine_speed`, ``docs/engine.md``)
* ``posecast bench latency`` - capture to display with SDK clients on loopback
  (:mod:`posecast.offline.evaluation.latency`, ``docs/latency-benchmark.md``)
* ``posecast serve [--dev] [--port N] ...`` - the pose-streaming server
  (:mod:`posecast.online.shell.app`, :mod:`posecast.online.config`, ``docs/server.md``)
* ``posecast token --room R --player P --role player`` - mint a development join token
  (:mod:`posecast.online.auth.tokens`)
* ``posecast demo`` - a server, two simulated headsets and a spectator on loopback
  (:mod:`posecast.demo`; what ``make run`` does)

Modules: one per command or small family of commands (:mod:`~posecast.cli.data`:
``data``; :mod:`~posecast.cli.train`: ``train`` and ``export``;
:mod:`~posecast.cli.evaluate`: ``eval`` and ``eval-apps``; :mod:`~posecast.cli.bench`:
``bench`` and ``bench engine``; :mod:`~posecast.cli.bench_latency`: ``bench latency``;
:mod:`~posecast.cli.serve`: ``serve``, ``token`` and ``demo``), each with its
commands' functions and an ``add_parsers`` (``bench latency``'s ``add_parser``, called
by ``bench``'s); :mod:`~posecast.cli.parser`, the
parser that gathers them and turns argparse's refusals into the CLI's errors;
:mod:`~posecast.cli.common`, what they share (hints, and the checks at the edge).

Errors: every failure a user can cause (a bad option value, a missing or unreadable
file, a model or dataset of the wrong kind) is a :class:`~posecast.errors.PosecastError`.
:func:`main` prints it as ``posecast: error [CODE]: message`` and a ``hint:`` line on
stderr, without a traceback, and exits 2. Anything else is a bug and keeps its traceback.
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence

from posecast.cli.common import HINT
from posecast.cli.parser import build_parser, parser_for
from posecast.errors import (
    AcclaimError,
    BvhError,
    DataError,
    DatasetError,
    ModelError,
    PosecastError,
    RigError,
)

__all__ = ["build_parser", "main"]


def _command(args: argparse.Namespace) -> str:
    """``"data prepare"``, ``"train"``, ...: the command as typed."""
    sub = getattr(args, "data_command", None) or getattr(args, "bench_command", None)
    return f"{args.command} {sub}" if sub else str(args.command)


def _hint_for(exc: PosecastError, command: str) -> str:
    """What to do about ``exc``: the hint it was raised with, else one for its kind."""
    for note in getattr(exc, "__notes__", ()):
        if isinstance(note, str) and note.startswith(HINT):
            return note[len(HINT) :]
    if isinstance(exc, BvhError):
        return (
            "check that the file is a readable BVH (plain or .gz); "
            "`posecast data prepare --skip-bad` leaves bad files out"
        )
    if isinstance(exc, AcclaimError):
        return (
            "check that the file is a readable ASF/AMC (plain or .gz) and that its subject's "
            ".asf sits beside the .amc; `posecast data prepare --skip-bad` leaves bad files out"
        )
    if isinstance(exc, RigError):
        return (
            "map the skeleton's joints in a rig *.json and pass its directory with "
            "`posecast data prepare --rigs DIR` (docs/data.md)"
        )
    if isinstance(exc, DatasetError):
        return "pass a directory written by `posecast data prepare --bvh DIR --out DIR`"
    if isinstance(exc, DataError):
        if command == "data prepare":
            return (
                "check the paths: each must exist, a --bvh one hold .bvh or .bvh.gz files, "
                "an --amc or --hdm05 one .amc or .amc.gz files with their .asf"
            )
        return "check the path: it must exist and hold .bvh or .bvh.gz files"
    if isinstance(exc, ModelError):
        return (
            "check the models directory (default: the shipped models), or re-export the "
            "models with `posecast export`"
        )
    return f"see `posecast {command} --help`"


def main(argv: Sequence[str] | None = None) -> int:
    args: argparse.Namespace | None = None
    try:
        parser = build_parser()
        args, extra = parser.parse_known_args(argv)
        if extra:  # named for the command they were given to, not for posecast's top level
            owner = parser_for(parser, _command(args))
            owner.print_usage(sys.stderr)
            raise owner.refusal(extra, f"unrecognized arguments: {' '.join(extra)}")
        return int(args.func(args))
    except PosecastError as exc:
        print(f"posecast: error [{exc.code}]: {exc}", file=sys.stderr)
        command = "" if args is None else _command(args)
        print(HINT + _hint_for(exc, command), file=sys.stderr)
        return 2
