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
* ``posecast serve [--dev] [--port N] ...`` - the pose-streaming server
  (:mod:`posecast.online.shell.app`, :mod:`posecast.online.config`, ``docs/server.md``)
* ``posecast token --room R --player P --role player`` - mint a development join token
  (:mod:`posecast.online.auth.tokens`)
* ``posecast demo`` - a server, two simulated headsets and a spectator on loopback
  (:mod:`posecast.demo`; what ``make run`` does)

Errors: every failure a user can cause (a bad option value, a missing or unreadable
file, a model or dataset of the wrong kind) is a :class:`~posecast.errors.PosecastError`.
:func:`main` prints it as ``posecast: error [CODE]: message`` and a ``hint:`` line on
stderr, without a traceback, and exits 2. Anything else is a bug and keeps its traceback.
"""

from __future__ import annotations

import argparse
import contextlib
import dataclasses
import difflib
import errno
import logging
import math
import os
import re
import socket
import sys
from collections.abc import Iterator, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any, NoReturn, TypeVar

from posecast.errors import (
    AcclaimError,
    BvhError,
    ConfigError,
    DataError,
    DatasetError,
    ModelError,
    PosecastError,
    RigError,
)
from posecast.tracking.layouts import Layout

if TYPE_CHECKING:  # the data stack loads only for the commands that need it
    from posecast.offline.dataset.store import SplitData

_HINT = "hint: "
_E = TypeVar("_E", bound=PosecastError)
_RESUME_HINT = "--resume continues the run in --out: drop it to start over, or pick another --out"


def _hinted(exc: _E, hint: str) -> _E:
    """``exc`` with the hint :func:`main` prints under it."""
    exc.add_note(_HINT + hint)
    return exc


def _config(message: str, hint: str) -> ConfigError:
    return _hinted(ConfigError(message), hint)


# --- Validation at the edge ----------------------------------------------------------


def _at_least(option: str, value: float, low: float, command: str) -> None:
    if not value >= low:  # NaN fails too
        raise _config(f"{option} {value} must be >= {low:g}", f"see `posecast {command} --help`")


def _samples(option: str, values: Sequence[int], command: str) -> None:
    """Latent sample counts N: 1 to the engine's MAX_SAMPLES (a larger N would stop the
    run later with a MemoryError traceback)."""
    from posecast.online.engine.config import MAX_SAMPLES

    for n in values:
        _at_least(option, n, 1, command)
        if n > MAX_SAMPLES:
            raise _config(
                f"{option} {n} must be <= {MAX_SAMPLES}",
                f"N = 100 is what the server runs; see `posecast {command} --help`",
            )


def _finite(option: str, value: float, command: str, *, positive: bool = False) -> None:
    if not math.isfinite(value) or value < 0 or (positive and value == 0):
        need = "a finite number > 0" if positive else "a finite number >= 0"
        raise _config(f"{option} {value} must be {need}", f"see `posecast {command} --help`")


def _float_arg(option: str, text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        value = math.nan
    if not math.isfinite(value) or value < 0:
        raise _config(f"{option} {text!r} must be a finite number >= 0", "e.g. 1.0, or `off`")
    return value


def _float_or_off(option: str, text: str | None, default: float | None) -> float | None:
    """An option given as a number >= 0 or `off` (``None``); ``default`` when absent."""
    if text is None:
        return default
    return None if text == "off" else _float_arg(option, text)


def _int_list(option: str, text: str, command: str) -> list[int]:
    """A comma-separated list of distinct integers >= 1 (``"1,10,100"``)."""
    try:
        values = [int(p) for p in text.split(",")]
    except ValueError:
        values = []
    if not values or min(values) < 1:
        raise _config(
            f"{option} {text!r} is not a comma-separated list of integers >= 1",
            f"e.g. {option} 1,10,100",
        )
    twice = [v for i, v in enumerate(values) if v in values[:i]]
    if twice:  # the same count measured twice: two figures for one row
        raise _config(
            f"{option} {text!r} names {twice[0]} twice: each count once",
            f"e.g. {option} 1,10,100",
        )
    return values


def _backends(option: str, text: str, command: str, *, many: bool = False) -> list[str]:
    """Backend names (``native``, ``onnx``, ``torch``); with ``many``, a comma-separated
    list of distinct ones (``"native,onnx"``)."""
    from posecast.online.engine.ports import BACKENDS

    names = [n.strip() for n in text.split(",")] if many else [text]
    if not all(n in BACKENDS for n in names) or len(set(names)) < len(names):
        what = "a comma-separated list of distinct backends" if many else "a backend"
        raise _config(
            f"{option} {text!r} is not {what}",
            f"use {'some' if many else 'one'} of {', '.join(BACKENDS)}, e.g. {option} "
            f"{'native,onnx' if many else 'onnx'} (`posecast {command} --help`)",
        )
    return names


def _json_out(path: Path | None) -> None:
    """Fail now, not after a long run, when the report could not be written."""
    if path is None:
        return
    if path.is_dir():
        raise _config(f"--json {path} is a directory", "name the file to write, e.g. report.json")
    if not path.parent.is_dir():
        raise _config(
            f"--json {path}: directory {path.parent} does not exist", "create it or pick another"
        )


def _out_dir(option: str, path: Path) -> None:
    """Fail now, not with a traceback at the first write, when the output directory
    cannot be made: the path, or a folder above it, is a file, or the nearest folder
    that exists is not writable."""
    if path.exists() and not path.is_dir():
        raise _config(f"{option} {path} exists and is not a directory", "pick a directory path")
    at = path.absolute()
    while not at.exists():
        at = at.parent
    if not at.is_dir():
        raise _config(f"{option} {path}: {at} is a file, not a directory", "pick a directory path")
    if not os.access(at, os.W_OK | os.X_OK):
        raise _config(f"{option} {path}: cannot write in {at}", "pick a directory you may write in")


def _models_dir(path: Path | None, option: str = "--models") -> None:
    if path is not None and not path.is_dir():
        raise _hinted(
            ModelError("no such models directory", path=path),
            f"pass the directory `posecast export --out` wrote, or leave out {option} "
            "for the shipped models",
        )


def _need(extra: str, *modules: str) -> None:
    """Fail with the install line when an optional dependency is missing."""
    import importlib.util

    for mod in modules:
        if importlib.util.find_spec(mod) is None:
            raise _config(
                f"this command needs the {mod!r} package (posecast[{extra}])",
                f"pip install 'posecast[{extra}]'",
            )


def _manifest(path: Path) -> dict[str, object]:
    """The manifest of a prepared dataset (:class:`DatasetError` if it is not one)."""
    from posecast.offline.dataset.store import read_manifest

    if not path.is_dir():
        raise DatasetError("no such dataset directory", path=path)
    return read_manifest(path)


def _split(path: Path, name: str, verb: str) -> SplitData:
    """The clips of split ``name`` of a prepared dataset (a :class:`DatasetError` with a
    hint to ``verb`` another split if it has none)."""
    from posecast.offline.dataset.split import SPLITS
    from posecast.offline.dataset.store import load_split

    _manifest(path)
    split = load_split(path, name)
    if split.n_clips == 0:
        raise _hinted(
            DatasetError(f"the {name} split has no clips", path=path),
            f"{verb} another --split (one of {', '.join(SPLITS)})",
        )
    return split


def _clip_frames(manifest: dict[str, object], split: str, path: Path) -> list[int]:
    """Frame counts of the clips of one split, from the manifest."""
    clips = manifest.get("clips")
    entries = clips.get(split) if isinstance(clips, dict) else None
    if not isinstance(entries, list):
        raise DatasetError(f"manifest lists no {split} split", path=path)
    try:
        return [int(c["frames"]) for c in entries]
    except (TypeError, KeyError, ValueError):
        raise DatasetError(f"manifest: bad clip entry in the {split} split", path=path) from None


def _need_clips(
    manifest: dict[str, object], path: Path, splits: Sequence[str], frames: int
) -> None:
    for split in splits:
        if not any(n >= frames for n in _clip_frames(manifest, split, path)):
            raise _hinted(
                DatasetError(
                    f"the {split} split has no clip of at least {frames} frames", path=path
                ),
                "prepare more data, or move subjects into that split with "
                "`posecast data prepare --split-file FILE`",
            )


def _checkpoint(
    option: str, path: Path, kind: str, layout: str | None = None, hint: str | None = None
) -> None:
    """Check that ``path`` is a checkpoint of ``kind`` (and tracker ``layout``)."""
    import pickle

    from posecast.offline.train.checkpoint import load_checkpoint

    how = f"posecast train {kind}" + (
        f" --layout {layout}" if layout in (Layout.HMD3, Layout.SITES) else ""
    )
    hint = hint or f"pass a checkpoint.pt written by `{how}` to {option}"
    if not path.is_file():
        raise _hinted(ModelError("no such checkpoint file", path=path), hint)
    try:
        state: Any = load_checkpoint(path)
    except (OSError, EOFError, RuntimeError, ValueError, pickle.UnpicklingError) as exc:
        raise _hinted(ModelError(f"not a checkpoint: {exc}", path=path), hint) from None
    if not isinstance(state, dict) or not {"model", "norm", "config"} <= state.keys():
        raise _hinted(ModelError("not a posecast checkpoint", path=path), hint)
    if state.get("kind") != kind:
        raise _hinted(
            ModelError(f"a {state.get('kind')!r} checkpoint, not {kind!r}", path=path), hint
        )
    if layout is not None:
        config = state["config"]
        got = (
            str(config.get("layout", Layout.HMD3_WAIST.value)) if isinstance(config, dict) else None
        )
        if got != layout:
            raise _hinted(
                ModelError(f"a checkpoint of layout {got!r}, not {layout!r}", path=path), hint
            )


# --- Commands --------------------------------------------------------------------------


def _cmd_data_clearance(args: argparse.Namespace) -> int:
    from posecast.offline.dataset.split import SPLITS

    if args.split not in SPLITS:
        raise _config(f"--split {args.split!r} unknown", f"use one of {', '.join(SPLITS)}")
    _finite("--percentile", args.percentile, "data clearance")
    if not 0.0 <= args.percentile <= 100.0:
        raise _config("--percentile must be within 0 to 100", "for example --percentile 5")
    from posecast.offline.dataset.clearance import clearance_table
    from posecast.offline.evaluation.reconstruct import clip_truth

    split = _split(args.data, args.split, "measure")
    clips = (clip_truth(split.clip(i))[1] for i in range(split.n_clips))
    centres, heights, counts = clearance_table(clips, split.fps, args.percentile)
    print(f"toe height, percentile {args.percentile:g}, {args.split} split ground truth")
    print("speed_m_s  toe_frames  clearance_m")
    for c, n, h in zip(centres, counts, heights, strict=True):
        print(f"{c:9.3f}  {n:10d}  {h:11.3f}")
    print(f"SPEEDS_M_S = {centres}")
    print(f"CLEARANCE_M = {heights}")
    return 0


def _cmd_data_wrists(args: argparse.Namespace) -> int:
    from posecast.offline.dataset.split import SPLITS

    if args.split not in SPLITS:
        raise _config(f"--split {args.split!r} unknown", f"use one of {', '.join(SPLITS)}")
    from posecast.offline.dataset.wrists import bend_summary
    from posecast.offline.evaluation.reconstruct import clip_truth

    split = _split(args.data, args.split, "measure")
    stats = bend_summary(clip_truth(split.clip(i)) for i in range(split.n_clips))
    print(f"wrist bend (forearm against a straight wrist), {args.split} split ground truth")
    for key, value in stats.items():
        print(f"{key:12s} {value:10.1f}")
    return 0


def _cmd_data_prepare(args: argparse.Namespace) -> int:
    if not (args.bvh or args.amc or args.hdm05):
        raise _config(
            "no motion to prepare",
            "pass --bvh DIR (BVH files), --amc DIR (ASF/AMC files) and/or --hdm05 DIR "
            "(the HDM05 set, CC BY-SA 3.0), each as often as needed",
        )
    _finite("--amc-fps", args.amc_fps, "data prepare", positive=True)
    _out_dir("--out", args.out)
    for d in args.rigs or ():
        if not d.is_dir():
            raise _config(f"--rigs {d}: no such directory", "pass a directory of rig *.json maps")
    _need("data", "scipy")
    from posecast.offline.dataset.prepare import prepare
    from posecast.offline.motion.rig import load_rigs

    rigs = load_rigs(args.rigs or ())
    names = [r.name for r in rigs]
    if args.rig is not None and args.rig not in names:
        raise _hinted(
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


@contextlib.contextmanager
def _listen_errors(host: str, port: int, hint: str) -> Iterator[None]:
    """Turn a socket that cannot be bound (port in use, unknown host) into a ConfigError."""
    try:
        yield
    except OSError as exc:
        bind = (errno.EADDRINUSE, errno.EADDRNOTAVAIL, errno.EACCES)
        if not isinstance(exc, socket.gaierror) and exc.errno not in bind:
            raise
        raise _config(f"cannot listen on {host}:{port}: {exc.strerror or exc}", hint) from None


def _cmd_demo(args: argparse.Namespace) -> int:
    import asyncio

    _at_least("--port", args.port, 0, "demo")
    if args.port > 65535:
        raise _config(f"--port {args.port} outside [0, 65535]", "0 picks any free port")
    _samples("--samples", [args.samples], "demo")
    if args.seconds is not None:
        _finite("--seconds", args.seconds, "demo", positive=True)
    _need("data", "scipy")
    from posecast.demo import run

    if args.bvh is not None:  # read it now: a bad file must fail before the server starts
        from posecast.offline.dataset.prepare import process_file
        from posecast.offline.motion.rig import load_rigs

        process_file(args.bvh, load_rigs())
    with (
        contextlib.suppress(KeyboardInterrupt),
        _listen_errors("127.0.0.1", args.port, "pick another --port (0: any free one)"),
    ):
        asyncio.run(run(args.port, args.seconds, args.bvh, args.samples))
    return 0


# The sequence trainers' defaults (posecast.offline.train.cvae_trainer), here so that
# the parser's help and the anomaly AE's checks need not import torch.
_KL_WEIGHT, _HIDDEN, _WINDOW, _BATCH = 1.0, 128, 60, 128


def _train_device(name: str) -> str:
    """``--device``: ``auto`` is CUDA when torch sees one, else the CPU; a named
    accelerator that torch cannot see is a configuration error."""
    import torch

    cuda = torch.cuda.is_available()
    if name == "auto":
        return "cuda" if cuda else "cpu"
    if name == "cuda" and not cuda:
        raise _config("--device cuda: torch sees no CUDA device", "use --device cpu or auto")
    return name


def _cmd_train(args: argparse.Namespace) -> int:
    import dataclasses

    cmd = "train"
    if args.steps is not None:
        _at_least("--steps", args.steps, 1, cmd)
    _at_least("--threads", args.threads, 1, cmd)
    _at_least("--seed", args.seed, 0, cmd)
    _finite("--rot-weight", args.rot_weight, cmd)
    _finite("--vel-weight", args.vel_weight, cmd)
    _finite("--lower-weight", args.lower_weight, cmd, positive=True)
    _finite("--kl-weight", args.kl_weight, cmd)
    _finite("--budget-min", args.budget_min, cmd)
    for option, value, low in (("--hidden", args.hidden, 64), ("--window", args.window, 2)):
        _at_least(option, value, low, cmd)
    _at_least("--batch", args.batch, 1, cmd)
    if args.hidden % 64:
        raise _config(
            f"--hidden {args.hidden} must be a multiple of 64",
            "the native kernels run GRUs 64 units at a time: pick 128, 192, 256, ...",
        )
    layout = Layout(args.layout)
    sequence_only = (
        layout != Layout.HMD3_WAIST
        or args.rot_weight
        or args.vel_weight
        or args.lower_weight != 1.0
        or args.no_orientation
        or args.kl_weight != _KL_WEIGHT
        or args.hidden != _HIDDEN
        or args.window != _WINDOW
        or args.batch != _BATCH
        or args.budget_min
        or args.device != "cpu"
    )
    if args.network == "anomaly":
        if sequence_only:
            raise _config(
                "--layout, --rot-weight, --vel-weight, --lower-weight, --kl-weight, --hidden, "
                "--window, --batch, --budget-min, --device and --no-orientation apply to cvae "
                "and ae only",
                "the anomaly AE reads poses, not trackers: drop those options",
            )
    elif args.network == "ae" and layout != Layout.HMD3_WAIST:
        raise _config(
            f"the AE ablation exists for the {Layout.HMD3_WAIST} layout only",
            f"drop --layout, or train `posecast train cvae --layout {layout}`",
        )
    elif args.no_orientation and layout == Layout.HMD3_WAIST:
        raise _config(
            f"--no-orientation: the {layout} features have no orientations",
            f"use it with --layout {Layout.HMD3}",
        )
    _out_dir("--out", args.out)
    manifest = _manifest(args.data)
    _need("train", "torch")
    ckpt = args.out / "checkpoint.pt"
    if args.network in ("cvae", "ae"):
        from posecast.offline.nets.cvae import CVAEConfig
        from posecast.offline.train.cvae_trainer import CVAETrainConfig, train_cvae
        from posecast.tracking.layouts import spec

        det = args.network == "ae"
        ls = spec(layout)
        model_cfg = CVAEConfig(
            n_features=ls.n_features,
            hidden=args.hidden,
            deterministic=det,
            encoder_sees_pose=not det,
            layout=str(ls.layout),
            root_outputs=ls.root_outputs,
        )
        cfg = CVAETrainConfig(
            threads=args.threads,
            seed=args.seed,
            rot_weight=args.rot_weight,
            vel_weight=args.vel_weight,
            lower_weight=args.lower_weight,
            kl_weight=args.kl_weight,
            window=args.window,
            batch=args.batch,
            budget_s=args.budget_min * 60.0,
            device=_train_device(args.device),
            no_orientation=args.no_orientation,
        )
        if args.steps is not None:
            cfg = dataclasses.replace(cfg, steps=args.steps)
        _need_clips(manifest, args.data, ("train", "val"), cfg.window)
        if args.resume and ckpt.exists():
            _checkpoint("--resume", ckpt, args.network, str(ls.layout), _RESUME_HINT)
        path = train_cvae(args.data, args.out, model_cfg, cfg, resume=args.resume)
    else:
        from posecast.offline.train.anomaly_trainer import AnomalyTrainConfig, train_anomaly

        acfg = AnomalyTrainConfig(threads=args.threads, seed=args.seed)
        if args.steps is not None:
            acfg = dataclasses.replace(acfg, steps=args.steps)
        _need_clips(manifest, args.data, ("train", "val"), 1)
        if args.resume and ckpt.exists():
            _checkpoint("--resume", ckpt, "anomaly", hint=_RESUME_HINT)
        path = train_anomaly(args.data, args.out, acfg, resume=args.resume)
    print(f"checkpoint: {path}")
    return 0


def _cmd_export(args: argparse.Namespace) -> int:
    jobs: list[tuple[str, Path | None, str, str | None]] = [
        ("--cvae", args.cvae, "cvae", Layout.HMD3_WAIST.value),
        ("--cvae-hmd3", args.cvae_hmd3, "cvae", Layout.HMD3.value),
        ("--cvae-sites", args.cvae_sites, "cvae", Layout.SITES.value),
        ("--ae", args.ae, "ae", Layout.HMD3_WAIST.value),
        ("--anomaly", args.anomaly, "anomaly", None),
    ]
    given = [(opt, path, kind, lay) for opt, path, kind, lay in jobs if path is not None]
    if not given:
        raise _config(
            "nothing to export",
            "pass one or more of --cvae, --cvae-hmd3, --cvae-sites, --ae, --anomaly",
        )
    _out_dir("--out", args.out)
    for option, path, _, _ in given:
        if not path.is_file():
            raise _hinted(
                ModelError("no such checkpoint file", path=path),
                f"pass the checkpoint.pt that `posecast train` wrote to {option}",
            )
    if args.data is not None:
        _need_clips(_manifest(args.data), args.data, ("train",), 1)
    _need("train", "torch", "onnx")
    for option, path, kind, layout in given:
        _checkpoint(option, path, kind, layout)
    from posecast.offline.train.export import export_all, mean_pose_rot6d

    extra = {}
    if args.data is not None:
        extra["cvae_decoder"] = {"mean_pose_rot6d": mean_pose_rot6d(args.data)}
    for path in export_all(
        args.out,
        args.cvae,
        args.ae,
        args.anomaly,
        extra,
        cvae_hmd3=args.cvae_hmd3,
        cvae_sites=args.cvae_sites,
    ):
        print(f"wrote {path}")
    return 0


def _cmd_eval(args: argparse.Namespace) -> int:
    import json

    from posecast.offline.dataset.split import SPLITS
    from posecast.offline.evaluation.runner import VARIANTS, evaluate, format_table
    from posecast.online.engine.config import EngineConfig
    from posecast.tracking.layouts import parse_layout
    from posecast.tracking.sites import TrackerSetError

    try:
        layout = parse_layout(args.layout)
    except TrackerSetError as exc:
        raise _config(
            f"--layout {args.layout!r}: {exc}",
            f"use {Layout.HMD3_WAIST}, {Layout.HMD3} or a tracker set such as "
            "head,left_hand,right_hand,waist,left_foot,right_foot",
        ) from None
    if args.variants is not None:
        variants = [v.strip() for v in args.variants.split(",")]
        unknown = [v for v in variants if v not in VARIANTS]
        if unknown or not variants or len(set(variants)) < len(variants):
            raise _config(
                f"--variants {args.variants!r}: not a comma-separated subset of the variants",
                f"use some of {', '.join(VARIANTS)}",
            )
    else:
        variants = list(VARIANTS)
        if args.layout != Layout.HMD3_WAIST:
            variants.remove("ae_ik")  # the AE ablation is a 4-point model
    if "ae_ik" in variants and args.layout != Layout.HMD3_WAIST:
        raise _config(
            f"variant ae_ik exists for the {Layout.HMD3_WAIST} layout only",
            f"drop ae_ik from --variants for --layout {args.layout}",
        )
    if args.data is not None and args.split not in SPLITS:
        raise _config(f"--split {args.split!r} unknown", f"use one of {', '.join(SPLITS)}")
    _samples("--samples", [args.samples], "eval")
    _finite("--outlier-factor", args.outlier_factor, "eval", positive=True)
    ssi_defaults = EngineConfig()
    latent_scale = ssi_defaults.latent_scale if args.latent_scale is None else args.latent_scale
    _finite("--latent-scale", latent_scale, "eval", positive=True)
    home = _float_or_off("--home-factor", args.home_factor, ssi_defaults.home_factor)
    (backend,) = _backends("--backend", args.backend, "eval")
    drift = _float_or_off("--ik-max-drift", args.ik_max_drift, ssi_defaults.ik_max_drift_m)
    release = ssi_defaults.ik_release_frames
    wrist = ssi_defaults.wrist_elbow if args.wrist_elbow is None else args.wrist_elbow
    if not 0.0 <= wrist <= 1.0:  # NaN included
        raise _config(f"--wrist-elbow {wrist} must be a share from 0 to 1", "e.g. 0.75, or 0")
    if args.ik_release_frames is not None:
        _at_least("--ik-release-frames", args.ik_release_frames, 1, "eval")
        release = args.ik_release_frames
    engine_cfg = EngineConfig(  # a ConfigError for a bad --samples or --home-factor
        samples=args.samples,
        outlier_baseline=args.outlier_baseline,
        outlier_factor=args.outlier_factor,
        upper_body_ik=not args.no_upper_ik,
        floor_ik=not args.no_floor_ik,
        swing_clearance=not args.no_swing_clearance,
        knee_hinge=not args.no_knee_hinge,
        wrist_elbow=wrist,
        elbow_hinge=not args.no_elbow_hinge,
        hand_reach=not args.no_hand_reach,
        torso_span=not args.no_torso_span,
        legs_apart=not args.no_legs_apart,
        pelvis_lean=not args.no_pelvis_lean,
        pelvis_smoothing=not args.no_pelvis_smoothing,
        floor_select=not args.no_floor_select,
        ik_max_drift_m=drift,
        ik_release_frames=release,
        latent_scale=latent_scale,
        home_factor=home,
    )
    _json_out(args.json)
    _models_dir(args.models)
    if "baseline_mean_lower_body" in variants:
        from posecast.online.inference.artifact import default_models_dir

        sidecar = (args.models or default_models_dir()) / "cvae_decoder.json"
        meta: Any = None
        with contextlib.suppress(OSError, ValueError):  # unreadable: load_artifact says so
            meta = json.loads(sidecar.read_text("utf-8"))
        if isinstance(meta, dict) and "mean_pose_rot6d" not in meta:
            raise _hinted(
                ModelError("the decoder sidecar has no mean_pose_rot6d", path=sidecar),
                "re-export with `posecast export --data DIR`, or leave "
                "baseline_mean_lower_body out of --variants",
            )

    if args.bvh is not None:
        _need("data", "scipy")
        from posecast.offline.dataset.prepare import find_bvh_files, process_file
        from posecast.offline.motion.rig import load_rigs

        files = find_bvh_files(args.bvh)
        if not files:
            raise DataError(f"{args.bvh}: no .bvh or .bvh.gz files found")
        rigs = load_rigs()
        clips = [process_file(p, rigs)[1] for p in files]
        fps = 60.0
    else:
        split = _split(args.data, args.split, "evaluate")
        clips = [split.clip(i) for i in range(split.n_clips)]
        fps = split.fps
    report = evaluate(
        clips,
        fps,
        variants,
        args.models,
        log=lambda m: print(m, file=sys.stderr),
        engine_cfg=engine_cfg,
        layout=layout,
        backend=backend,
    )
    print(format_table(report))
    if args.json is not None:
        args.json.write_text(json.dumps(report, indent=1) + "\n", encoding="utf-8")
        print(f"wrote {args.json}")
    return 0


def _cmd_eval_apps(args: argparse.Namespace) -> int:
    import json

    counts = _int_list("--samples", args.samples, "eval-apps")
    _samples("--samples", counts, "eval-apps")
    _at_least("--runs", args.runs, 1, "eval-apps")
    _at_least("--threads", args.threads, 1, "eval-apps")
    _finite("--latent-scale", args.latent_scale, "eval-apps", positive=True)
    (backend,) = _backends("--backend", args.backend, "eval-apps")
    _json_out(args.json)
    _models_dir(args.models)
    _manifest(args.data)
    from posecast.offline.dataset.store import load_split
    from posecast.offline.evaluation.applications import table3
    from posecast.online.inference.auto import load_backend

    kick = None
    names: list[str] = []
    for split_name in ("train", "val", "test"):
        split = load_split(args.data, split_name)
        for i, meta in enumerate(split.clips):
            names.append(str(meta["name"]))
            if meta["name"] == args.clip:
                kick = split.clip(i)
    if kick is None:
        shown = ", ".join(names[:8]) + (", ..." if len(names) > 8 else "")
        raise _config(
            f"--clip {args.clip!r} is not in {args.data}",
            f"pass the name of a clip of the dataset ({shown or 'it has none'})",
        )
    loaded = load_backend(backend, Layout.HMD3_WAIST, args.models, args.threads)
    report = table3(
        loaded, kick, sample_counts=counts, runs=args.runs, latent_scale=args.latent_scale
    )
    report["clip"] = args.clip
    print(json.dumps(report, indent=1))
    if args.json is not None:
        args.json.write_text(json.dumps(report, indent=1) + "\n", encoding="utf-8")
    return 0


def _cmd_bench_engine(args: argparse.Namespace) -> int:
    import json

    cmd = "bench engine"
    counts = _int_list("--players", args.players, cmd)
    _samples("--samples", [args.samples], cmd)
    for option, value in (
        ("--threads", args.threads),
        ("--ticks", args.ticks),
        ("--naive-players", args.naive_players),
    ):
        _at_least(option, value, 1, cmd)
    if not 0.0 <= args.hmd3_share <= 1.0:
        raise _config(
            f"--hmd3-share {args.hmd3_share} outside [0, 1]",
            "the share of players on the headset-only model, e.g. 0.5 (0: none)",
        )
    backends = _backends("--backend", args.backend, cmd, many=True)
    _json_out(args.json)
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


def _print_bench(report: dict[str, Any], samples: int) -> None:
    """One backend's tables of ``posecast bench engine``."""
    from posecast.offline.evaluation.engine_speed import realtime_summary

    used, asked = report["backend"], report["backend_asked"]
    print(f"backend {used}" + (f" ({asked} asked for; unavailable)" if used != asked else ""))
    print(f"{'players':>8s} {'p50 ms':>8s} {'p99 ms':>8s} {'GFLOP/s':>8s} {'MB/player':>10s}")
    for i, p in enumerate(report["players"]):
        print(
            f"{p:8d} {report['tick_p50_ms'][i]:8.2f} {report['tick_p99_ms'][i]:8.2f} "
            f"{report['gflops'][i]:8.1f} {report['rss_mb_per_player'][i]:10.2f}"
        )
    fit = realtime_summary(report["players"], report["tick_p99_ms"])
    print(f"max players at 60 Hz (p99 < 16.7 ms), N={samples}: {fit}")
    if report["native_isa"]:
        print(f"native kernels: {report['native_isa']}")
    print(f"naive loop: {report['naive_loop']}")
    both = report.get("both_models")
    if both:
        print(
            f"both models loaded (backend {both['backend']}), {both['hmd3_share']:.0%} of the "
            "players headset-only:"
        )
        print(f"{'players':>8s} {'hmd3':>5s} {'p50 ms':>8s} {'p99 ms':>8s} {'MB/player':>10s}")
        for i, p in enumerate(report["players"]):
            print(
                f"{p:8d} {both['hmd3_players'][i]:5d} {both['tick_p50_ms'][i]:8.2f} "
                f"{both['tick_p99_ms'][i]:8.2f} {both['rss_mb_per_player'][i]:10.2f}"
            )
        fit = realtime_summary(report["players"], both["tick_p99_ms"])
        print(f"max players at 60 Hz, both models: {fit}")
    sets = report.get("mixed_sets")
    if sets:
        print(
            f"mixed tracker sets on the sites model (backend {sets['backend']}), players on "
            f"{', '.join(sets['sets'])} in turn, beside hmd3+waist (p50 ratio):"
        )
        print(f"{'players':>8s} {'p50 ms':>8s} {'p99 ms':>8s} {'ratio':>6s} {'MB/player':>10s}")
        for i, p in enumerate(report["players"]):
            print(
                f"{p:8d} {sets['tick_p50_ms'][i]:8.2f} {sets['tick_p99_ms'][i]:8.2f} "
                f"{sets['p50_ratio'][i]:6.2f} {sets['rss_mb_per_player'][i]:10.2f}"
            )
        fit = realtime_summary(report["players"], sets["tick_p99_ms"])
        print(f"max players at 60 Hz, mixed sets: {fit}")


def _cmd_serve(args: argparse.Namespace) -> int:
    import asyncio
    import os

    from posecast.online.config import (
        FLAGS_GIVEN,
        MIN_SECRET_CHARS,
        ServerConfig,
        setting_names,
        unknown_variables,
    )
    from posecast.online.shell.app import serve_until_signal
    from posecast.online.shell.logging import configure

    flags: dict[str, str] = getattr(args, FLAGS_GIVEN, None) or {}
    skip = ("command", "func", FLAGS_GIVEN)
    overrides = {k: v for k, v in vars(args).items() if k not in skip}
    try:  # an error names each setting as typed: its flag, else its POSECAST_* variable
        cfg = ServerConfig.from_sources(os.environ, overrides, flags)
    except ConfigError as exc:
        if "token secret" in exc.message:
            hint = (
                f"export POSECAST_TOKEN_SECRET=<{MIN_SECRET_CHARS}+ random characters, the "
                "game backend's key>, or pass --dev for a throwaway one"
            )
        else:
            hint = "set it by its flag or POSECAST_* variable: see `posecast serve --help`"
        raise _hinted(exc, hint + " (docs/server.md)") from None
    named = setting_names(os.environ, overrides, flags)["models_dir"]
    _models_dir(Path(cfg.models_dir) if cfg.models_dir else None, named)
    configure(cfg.log_level)
    for name, meant in unknown_variables(os.environ).items():
        logging.getLogger("posecast.server").warning(
            "unknown setting ignored", extra={"variable": name, "did_you_mean": meant}
        )
    invented = cfg.dev and not os.environ.get("POSECAST_TOKEN_SECRET")
    if invented:
        print(f"posecast: --dev: token secret for this run: {cfg.token_secret}", flush=True)

    def ready(port: int) -> None:
        # An IPv6 host in brackets, as a URL writes it (ws://[::]:8765, not ws://:::8765);
        # "" is every IPv4 and every IPv6 interface (ws://:8765 named neither).
        host = f"[{cfg.host}]" if ":" in cfg.host else cfg.host
        where = f"ws://{host}:{port}" if host else f"ws://0.0.0.0:{port} and ws://[::]:{port}"
        print(f"posecast: listening on {where}", flush=True)
        if cfg.dev:
            secret = cfg.token_secret if invented else None
            print("\n".join(_dev_lines(cfg.host, port, secret)), flush=True)

    with _listen_errors(cfg.host, cfg.port, "pick another --port (0: any free one) or --host"):
        asyncio.run(serve_until_signal(cfg, ready))
    return 0


def _dev_lines(host: str, port: int, secret: str | None) -> list[str]:
    """What ``posecast serve --dev`` prints once it listens: the viewer's URL and, for
    an invented secret, ``export`` lines to paste into a client's shell (the names the
    SDK tools and the README's snippets read). The URLs are loopback ones where the
    bind covers one (:func:`_loopback_at`): the viewer's dev tokens are handed to
    loopback clients only, so a server bound elsewhere gets no viewer line but a word
    on why."""
    import shlex

    at = _loopback_at(host)
    if at is not None:
        lines = [f"posecast: --dev: viewer at http://{at}:{port}/viewer/ (this machine only)"]
    else:
        at = f"[{host}]" if ":" in host else host
        lines = [
            f"posecast: --dev: no viewer here: its dev tokens need a loopback bind, and "
            f"host {host} is not one (--host 127.0.0.1, the default, or 0.0.0.0 is)"
        ]
    if secret is not None:
        lines += [
            "posecast: --dev: for a client in another shell, paste:",
            f"export POSECAST_TOKEN_SECRET={shlex.quote(secret)}",
            f"export POSECAST_URL=ws://{at}:{port}/",
        ]
    return lines


def _loopback_at(host: str) -> str | None:
    """The loopback address, as a URL writes it (``127.0.0.1``, ``[::1]``), at which a
    client on this machine reaches a server bound to ``host``, or ``None`` where the
    bind covers none. The server binds every address ``host`` resolves to, as asyncio
    resolves it (``''``: every interface, IPv4 and IPv6), each IPv6 one IPv6-only:
    ``::`` is reached at ``[::1]``, never at 127.0.0.1. What counts as loopback is the
    viewer routes' own rule (``shell.http.is_loopback_address``, which refuses the others)."""
    import ipaddress

    from posecast.online.shell.http import is_loopback_address

    try:
        infos = socket.getaddrinfo(
            host or None, 0, type=socket.SOCK_STREAM, flags=socket.AI_PASSIVE
        )
    except OSError:
        return None
    reached = []
    for *_, sockaddr in infos:
        ip = ipaddress.ip_address(str(sockaddr[0]).split("%", 1)[0])
        at = ("127.0.0.1" if ip.version == 4 else "::1") if ip.is_unspecified else str(ip)
        if is_loopback_address(at):
            reached.append(at)
    if not reached:
        return None
    at = min(reached, key=lambda a: ":" in a)  # IPv4 first
    return f"[{at}]" if ":" in at else at


def _cmd_token(args: argparse.Namespace) -> int:
    import os
    import time

    from posecast.online.auth.tokens import MAX_TTL_S, mint
    from posecast.online.config import MIN_SECRET_CHARS

    secret = args.secret or os.environ.get("POSECAST_TOKEN_SECRET", "")
    if not secret:
        raise _config(
            "no token secret", "pass --secret KEY or set POSECAST_TOKEN_SECRET (the server's key)"
        )
    if len(secret) < MIN_SECRET_CHARS:
        raise _config(
            f"the token secret must be at least {MIN_SECRET_CHARS} characters",
            "use the secret the server runs with (POSECAST_TOKEN_SECRET)",
        )
    if not 0 < args.ttl <= MAX_TTL_S:
        raise _config(
            f"--ttl {args.ttl} outside [1, {MAX_TTL_S}] seconds", "e.g. --ttl 3600 (one hour)"
        )
    if not args.room or not args.player:
        raise _config("--room and --player must not be empty", "e.g. --room lobby --player p-17")
    rooms = tuple(r for r in (args.rooms or "").split(",") if r)
    if rooms and args.role != "backend":
        raise _config("only a backend token may list --rooms", "add --role backend or drop --rooms")
    try:
        token = mint(
            secret.encode("utf-8"),
            room=args.room,
            player=args.player,
            role=args.role,
            ttl_s=args.ttl,
            now=time.time(),
            rooms=rooms,
        )
    except ValueError as exc:  # mint's own checks of the values above
        raise _config(str(exc), "see `posecast token --help`") from None
    print(token)
    return 0


_NEGATIVE_NUMBER = re.compile(r"^-\d+$|^-\d*\.\d+$")  # a value to argparse, not an option


class _Parser(argparse.ArgumentParser):
    """argparse whose refusals (an unknown option, a missing or malformed value, no
    command) print the usage and raise a :class:`ConfigError` hinted with the
    command's ``--help``, which :func:`main` prints as every other user error.
    Subcommand parsers are made of this class too (argparse's ``add_subparsers`` takes
    the parent's class).

    The first wrong word of a command is the one reported (:meth:`refusal`): argparse
    finds a missing argument or command before it looks at the words it did not
    know, so ``posecast --bogus`` said a command was missing and
    ``posecast token --room R --plyer P`` that ``--player`` was. An unknown option or
    command is named with the nearest valid one."""

    _argv: Sequence[str] = ()  # the words this parser was last given (its command's own)

    def parse_known_args(  # type: ignore[override]
        self, args: Sequence[str] | None = None, namespace: argparse.Namespace | None = None
    ) -> tuple[argparse.Namespace, list[str]]:
        self._argv = list(sys.argv[1:] if args is None else args)
        return super().parse_known_args(self._argv, namespace)

    def error(self, message: str) -> NoReturn:
        self.print_usage(sys.stderr)
        raise self.refusal(self._argv, message)

    def refusal(self, argv: Sequence[str], message: str) -> ConfigError:
        """The error for ``argv`` (this command's words), which argparse refused with
        ``message``: an unknown option or command, in the order typed, else a missing
        command, else ``message``."""
        commands = self.commands()
        hidden: list[str] = []  # the values of secret options: never shown
        dashed = ""  # an option whose value starts with '-' (argparse takes it for one)
        value_next = False
        for i, arg in enumerate(argv):
            if value_next:  # the value of the option before it, whatever it looks like
                value_next = False
                continue
            if arg == "--":  # every word after it is a value (the first one a command)
                rest = argv[i + 1 : i + 2]
                if commands and rest and rest[0] not in commands:
                    return self._unknown_command(rest[0], commands)
                break
            if _is_option(arg):
                if not self._knows(arg):
                    return self._unknown_option(arg.split("=", 1)[0])
                actions = self._actions_of(arg)
                secret = any(a.dest in _secret_dests() for a in actions)
                attached = _attached_value(arg, actions)
                if attached is not None:  # --opt=V, -xV
                    if secret:
                        hidden.append(attached)
                elif any(a.nargs != 0 for a in actions) and i + 1 < len(argv):
                    word = argv[i + 1]
                    if secret:
                        hidden.append(word)
                    if _is_option(word):
                        dashed = dashed or _typed_option(arg, actions)
                    if word != "--" and not (_is_option(word) and self._knows(word)):
                        value_next = True
            elif commands:
                if arg not in commands:
                    return self._unknown_command(arg, commands)
                return commands[arg].refusal(argv[i + 1 :], message)  # the rest are its
        else:
            if commands:
                return _config(
                    f"`{self.prog}` needs a command: {', '.join(commands)}",
                    f"see `{self.prog} --help` for the commands",
                )
        message = _redact(message, hidden)
        if dashed and "expected one argument" in message:
            return _config(
                message,
                f"a value that starts with '-' goes after '=' ({dashed}=VALUE); "
                f"see `{self.prog} --help` for the options",
            )
        return _usage_error(self.prog, message)

    def commands(self) -> dict[str, _Parser]:
        """This command's subcommands (none for a leaf)."""
        for action in self._actions:
            if isinstance(action, argparse._SubParsersAction):
                return dict(action.choices)
        return {}

    def options(self) -> list[str]:
        return [s for action in self._actions for s in action.option_strings]

    def _knows(self, arg: str) -> bool:
        name = arg.split("=", 1)[0]
        options = self.options()
        if name in options:
            return True
        if name.startswith("--"):  # an abbreviation, as argparse takes (or refuses) it
            return self.allow_abbrev and any(o.startswith(name) for o in options)
        return arg[:2] in options  # -vq, -xVALUE

    def _actions_of(self, arg: str) -> list[argparse.Action]:
        """The options ``arg`` (one :meth:`_knows`) may stand for: one, or those an
        abbreviation matches."""
        name = arg.split("=", 1)[0]
        exact = [a for a in self._actions if name in a.option_strings]
        if exact:
            return exact
        if name.startswith("--"):
            return [a for a in self._actions if any(o.startswith(name) for o in a.option_strings)]
        return [a for a in self._actions if arg[:2] in a.option_strings]

    def _unknown_option(self, name: str) -> ConfigError:
        # Compared without the dashes, which every option shares (--bogus is not like
        # --layouts); a long option before a short one of the same letters.
        by_name = {o.lstrip("-"): o for o in sorted(self.options(), key=len, reverse=True)}
        near = difflib.get_close_matches(name.lstrip("-"), list(by_name), n=1, cutoff=0.6)
        if near:
            hint = f"did you mean {by_name[near[0]]}? see `{self.prog} --help` for the options"
        else:
            owners = [p.prog for p in _leaves(self) if p is not self and p._knows(name)]
            if owners:  # an option typed before its command
                hint = f"an option goes after its command: `{owners[0]} {name}`"
            else:
                hint = f"see `{self.prog} --help` for the options"
        return _config(f"unknown option {name}", hint)

    def _unknown_command(self, word: str, commands: dict[str, _Parser]) -> ConfigError:
        near = difflib.get_close_matches(word, list(commands), n=1, cutoff=0.6)
        help_ = f"see `{self.prog} --help` for the commands"
        hint = f"did you mean `{self.prog} {near[0]}`? {help_}" if near else help_
        return _config(
            f"unknown command {word!r} for `{self.prog}` (one of {', '.join(commands)})", hint
        )


def _is_option(arg: str) -> bool:
    """``arg`` is an option to argparse (``-x``, ``--name``, ``--name=V``), not a value."""
    return arg.startswith("-") and arg != "-" and not _NEGATIVE_NUMBER.match(arg) and " " not in arg


def _attached_value(arg: str, actions: Sequence[argparse.Action]) -> str | None:
    """The value typed in ``arg`` itself (``--opt=V``, ``-xV``), else ``None``."""
    if "=" in arg and arg.startswith("--"):
        return arg.split("=", 1)[1]
    if not arg.startswith("--") and len(arg) > 2 and all(a.nargs != 0 for a in actions):
        return arg[3:] if arg[2] == "=" else arg[2:]
    return None


def _typed_option(arg: str, actions: Sequence[argparse.Action]) -> str:
    """The option ``arg`` names, as typed (``--redis``), an abbreviation of one in
    full (``--sec``: ``--secret``)."""
    name = arg.split("=", 1)[0]
    spelt = [o for a in actions for o in a.option_strings if o.startswith(name)]
    return name if name in spelt or len(spelt) != 1 else spelt[0]


def _secret_dests() -> frozenset[str]:
    """The options whose values are never shown: ``token --secret`` and the server
    settings kept out of the config's repr (the token secret; a Redis URL, which may
    carry a password)."""
    from posecast.online.config import ServerConfig

    return frozenset({"secret"} | {f.name for f in dataclasses.fields(ServerConfig) if not f.repr})


def _redact(message: str, hidden: Sequence[str]) -> str:
    """``message`` with each word of ``hidden`` shown as ``<hidden>`` where it stands
    as a value: a word of its own, quoted as argparse quotes one, or after '='."""
    for word in hidden:
        if word:
            message = re.sub(
                rf"(?:^|(?<=[\s'\"=])){re.escape(word)}(?=$|[\s'\"])", "<hidden>", message
            )
    return message


def _leaves(parser: _Parser) -> Iterator[_Parser]:
    """``parser`` and every command under it that takes no further command."""
    commands = parser.commands()
    if not commands:
        yield parser
    for sub in commands.values():
        yield from _leaves(sub)


def _parser_for(parser: _Parser, command: str) -> _Parser:
    """The parser of ``command`` (``"data prepare"``) under ``parser``."""
    for word in command.split():
        parser = parser.commands().get(word, parser)
    return parser


def _usage_error(prog: str, message: str) -> ConfigError:
    return _config(message, f"see `{prog} --help` for the options")


# What ``posecast --help`` says (the module docstring is for developers).
_DESCRIPTION = (
    "Full-body poses for VR players from a headset and its controllers (with or without "
    "a waist tracker, or any tracker set), streamed live to everyone in a room; and the "
    "tools that prepare the motion data, train, export, evaluate and benchmark the models."
)
_EPILOG = (
    "Start with `posecast demo` (a server and two simulated headsets, with a live 3D viewer) or "
    "`posecast serve --dev`; `posecast COMMAND --help` gives a command's options. "
    "Docs: README.md, docs/server.md."
)


def build_parser() -> _Parser:
    parser = _Parser(prog="posecast", description=_DESCRIPTION, epilog=_EPILOG)
    sub = parser.add_subparsers(dest="command", required=True)

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
    prep.set_defaults(func=_cmd_data_prepare)

    clear = data_sub.add_parser(
        "clearance", help="how high real toes keep off the floor at each speed (the engine's table)"
    )
    clear.add_argument("--data", required=True, type=Path, help="prepared dataset directory")
    clear.add_argument("--split", default="train", help="split to measure (default train)")
    clear.add_argument(
        "--percentile", type=float, default=5.0, help="height percentile per speed (default 5)"
    )
    clear.set_defaults(func=_cmd_data_clearance)

    wrists = data_sub.add_parser(
        "wrists", help="how far real wrists bend (behind the engine's elbow hint)"
    )
    wrists.add_argument("--data", required=True, type=Path, help="prepared dataset directory")
    wrists.add_argument("--split", default="val", help="split to measure (default val)")
    wrists.set_defaults(func=_cmd_data_wrists)

    train = sub.add_parser("train", help="train a network (needs posecast[train])")
    train.add_argument("network", choices=("cvae", "ae", "anomaly"))
    train.add_argument("--data", required=True, type=Path, help="prepared dataset directory")
    train.add_argument("--out", required=True, type=Path, help="run directory (checkpoint.pt)")
    train.add_argument(
        "--steps", type=int, default=None, help="iterations (default: 12000; anomaly 20000)"
    )
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
        "--lower-weight",
        type=float,
        default=1.0,
        help="weight of the leg joints in the position loss against 1 for the others "
        "(1: all alike, as the shipped weights; docs/model-card.md)",
    )
    train.add_argument(
        "--vel-weight",
        type=float,
        default=0.0,
        help="weight of the joint-velocity loss, cm^2 per frame (0: none, as the earlier "
        "weights; docs/model-card.md)",
    )
    train.add_argument(
        "--kl-weight",
        type=float,
        default=_KL_WEIGHT,
        help=f"weight of the KL term (default {_KL_WEIGHT:g})",
    )
    train.add_argument(
        "--hidden",
        type=int,
        default=_HIDDEN,
        help=f"GRU width, a multiple of 64 (default {_HIDDEN})",
    )
    train.add_argument(
        "--window", type=int, default=_WINDOW, help=f"frames per window (default {_WINDOW})"
    )
    train.add_argument(
        "--batch", type=int, default=_BATCH, help=f"windows per step (default {_BATCH})"
    )
    train.add_argument(
        "--device",
        default="cpu",
        choices=("cpu", "cuda", "auto"),
        help="where to train (default cpu; auto: CUDA when torch sees one)",
    )
    train.add_argument(
        "--budget-min",
        type=float,
        default=0.0,
        help="wall-time budget in minutes, data loading included: the run plans its steps "
        "(at most --steps) to end, its learning-rate decay included, inside it (0: none)",
    )
    train.add_argument(
        "--layout",
        default=Layout.HMD3_WAIST.value,
        choices=[layout.value for layout in Layout],
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
    export.add_argument(
        "--cvae-sites", type=Path, help="tracker-set (sites) CVAE checkpoint, any set"
    )
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
        default=Layout.HMD3_WAIST.value,
        help="tracker layout: hmd3+waist (default) or hmd3 (their dedicated models), or a "
        "tracker set for the one model of every set, sites in wire order, inertial ones "
        "suffixed :imu (head,left_hand,right_hand,left_foot:imu,right_foot:imu)",
    )
    ev.add_argument("--samples", type=int, default=100, help="SSI latent samples N (100)")
    ev.add_argument(
        "--backend",
        default="native",
        help="inference backend of the SSI engine: native (default; falls back to onnx "
        "where the extension does not load), onnx or torch",
    )
    ev.add_argument("--outlier-factor", type=float, default=2.0, help="SSI outlier factor (2)")
    ev.add_argument(
        "--ik-max-drift",
        default=None,
        metavar="M|off",
        help="contact IK: release a lock once the network's ankle is M metres from it, or "
        "`off` to hold it for the whole predicted contact (default: the engine's)",
    )
    ev.add_argument(
        "--ik-release-frames",
        type=int,
        default=None,
        help="contact IK: frames a released foot blends back over (default: the engine's)",
    )
    ev.add_argument(
        "--outlier-baseline",
        default="zero",
        choices=("min", "zero"),
        help="SSI outlier rule: R_c > 2r (zero, the paper; default) or R_c - min R > 2r (min)",
    )
    ev.add_argument(
        "--latent-scale",
        type=float,
        default=None,
        help="SSI: scale of the pool's latents (1 = the prior; default: the engine's)",
    )
    ev.add_argument(
        "--home-factor",
        default=None,
        help="SSI: return to sample 0 (eps = 0) when it scores under this times r, or "
        "`off` for the paper's selector (default: the engine's)",
    )
    ev.add_argument(
        "--no-upper-ik",
        action="store_true",
        help="cvae_ik and cvae_ik_ssi without the upper-body pass (head and hands on their "
        "trackers): the network's own upper body",
    )
    ev.add_argument(
        "--no-floor-ik",
        action="store_true",
        help="cvae_ik, ae_ik and cvae_ik_ssi without the floor pass (feet below y = 0 "
        "lifted onto it): the network's and the contact IK's own feet",
    )
    ev.add_argument(
        "--no-swing-clearance",
        action="store_true",
        help="the floor pass without the swing clearance (a toe lifted to the height real "
        "toes keep at its speed): only feet below y = 0 are lifted",
    )
    ev.add_argument(
        "--wrist-elbow",
        type=float,
        default=None,
        metavar="SHARE",
        help="cvae_ik, ae_ik and cvae_ik_ssi: the share of each elbow's placement taken "
        "from its controller's rotation, 0 to 1 (default 0.75; 0: the network's elbow)",
    )
    ev.add_argument(
        "--no-elbow-hinge",
        action="store_true",
        help="cvae_ik, ae_ik and cvae_ik_ssi without the elbow hinge (upper arm and forearm "
        "turned so each elbow bends as a hinge, no joint moving)",
    )
    ev.add_argument(
        "--no-hand-reach",
        action="store_true",
        help="headset-only and sites players without a waist: leave the guessed pelvis "
        "where the headset puts it, not moved toward a controller beyond the arm",
    )
    ev.add_argument(
        "--no-torso-span",
        action="store_true",
        help="headset-only and sites players without a waist: leave the guessed body "
        "where the reach put it, the spine chain folding to the headset, not moved along "
        "the line to the headset until the network's torso spans it",
    )
    ev.add_argument(
        "--no-legs-apart",
        action="store_true",
        help="let the contact IK hold a foot where the other leg passes through it, "
        "not give way just as far as keeps the legs apart",
    )
    ev.add_argument(
        "--no-pelvis-lean",
        action="store_true",
        help="headset-only and sites players without a waist: leave the guessed pelvis "
        "as the network turned it, not leant so that the line to the head meets the headset",
    )
    ev.add_argument(
        "--no-floor-select",
        action="store_true",
        help="cvae_ik_ssi: keep in the pool samples with a foot deeper below the floor "
        "than the floor pass lifts (by default SSI never moves to one, and leaves one)",
    )
    ev.add_argument(
        "--no-knee-hinge",
        action="store_true",
        help="cvae_ik, ae_ik and cvae_ik_ssi without the knee hinge (thigh and shin turned "
        "so each knee bends as a hinge, no joint moving)",
    )
    ev.add_argument(
        "--no-pelvis-smoothing",
        action="store_true",
        help="cvae_ik, ae_ik and cvae_ik_ssi on each frame's own pelvis instead of its "
        "1-2-1 average with the frames either side",
    )
    ev.set_defaults(func=_cmd_eval)

    apps = sub.add_parser("eval-apps", help="Table 3: target hitting and collision avoidance")
    apps.add_argument("--data", type=Path, required=True, help="prepared dataset directory")
    apps.add_argument("--clip", default="135_04", help="kick clip name (default: 135_04)")
    apps.add_argument("--samples", default="1,10,100,1000", help="sample counts")
    apps.add_argument("--runs", type=int, default=100, help="runs (seeds) per setting")
    apps.add_argument("--models", type=Path, help="models directory (default: shipped)")
    apps.add_argument("--threads", type=int, default=2)
    apps.add_argument(
        "--latent-scale",
        type=float,
        default=1.0,
        help="the pool's latents are SCALE x eps (1: the prior, as streaming uses)",
    )
    apps.add_argument(
        "--backend", default="native", help="inference backend: native (default), onnx or torch"
    )
    apps.add_argument("--json", type=Path, help="write the report here")
    apps.set_defaults(func=_cmd_eval_apps)

    bench = sub.add_parser("bench", help="benchmarks")
    bench_sub = bench.add_subparsers(dest="bench_command", required=True)
    be = bench_sub.add_parser(
        "engine",
        help="per-tick cost of the SSI engine",
        description="The engine's whole per-tick cost at each player count, and how many "
        "players hold 60 Hz (p99 tick under 16.7 ms) as far as the counts tested tell.",
    )
    be.add_argument(
        "--players",
        default="1,10,50,100,200",
        help="player counts, comma-separated, each measured in turn (default %(default)s)",
    )
    be.add_argument(
        "--samples", type=int, default=100, help="latent samples N (default %(default)s)"
    )
    be.add_argument(
        "--threads",
        type=int,
        default=2,
        help="the backend's intra-op threads (default %(default)s)",
    )
    be.add_argument(
        "--backend",
        default="native",
        help="inference backend, or a comma-separated list to run each in turn, one table "
        "each (native, onnx, torch; default native, which falls back to onnx where the "
        "extension does not load; --json then writes a list)",
    )
    be.add_argument(
        "--ticks", type=int, default=120, help="measured ticks per count (default %(default)s)"
    )
    be.add_argument(
        "--naive-players",
        type=int,
        default=10,
        help="players for the per-player loop it is compared with (default %(default)s)",
    )
    be.add_argument(
        "--hmd3-share",
        type=float,
        default=0.5,
        help="also load the headset-only model and run this share of players on it "
        "(default 0.5; 0: the 4-point model only)",
    )
    be.add_argument(
        "--sets",
        action="store_true",
        help="also run every player on the one model of every tracker set, the six sets of "
        "the evaluation table in turn, beside the 4-point figure count by count",
    )
    be.add_argument("--json", type=Path, help="write the report here")
    be.set_defaults(func=_cmd_bench_engine)

    from posecast.online.config import add_arguments

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


def _command(args: argparse.Namespace) -> str:
    """``"data prepare"``, ``"train"``, ...: the command as typed."""
    sub = getattr(args, "data_command", None) or getattr(args, "bench_command", None)
    return f"{args.command} {sub}" if sub else str(args.command)


def _hint_for(exc: PosecastError, command: str) -> str:
    """What to do about ``exc``: the hint it was raised with, else one for its kind."""
    for note in getattr(exc, "__notes__", ()):
        if isinstance(note, str) and note.startswith(_HINT):
            return note[len(_HINT) :]
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
            owner = _parser_for(parser, _command(args))
            owner.print_usage(sys.stderr)
            raise owner.refusal(extra, f"unrecognized arguments: {' '.join(extra)}")
        return int(args.func(args))
    except PosecastError as exc:
        print(f"posecast: error [{exc.code}]: {exc}", file=sys.stderr)
        command = "" if args is None else _command(args)
        print(_HINT + _hint_for(exc, command), file=sys.stderr)
        return 2


if __name__ == "__main__":  # pragma: no cover
    raise SystemExit(main())
