"""``posecast train`` (a network, checkpointing to ``RUN/checkpoint.pt``;
:mod:`posecast.offline.train.cvae_trainer`, :mod:`posecast.offline.train.anomaly_trainer`;
needs ``posecast[train]``) and ``posecast export`` (checkpoints -> ONNX models and
JSON sidecars, :mod:`posecast.offline.train.export`)."""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any

from posecast.cli.common import (
    at_least,
    check_checkpoint,
    check_out_dir,
    config_error,
    dataset_manifest,
    finite,
    given,
    hinted,
    need,
    need_clips,
)
from posecast.errors import ModelError
from posecast.tracking.layouts import Layout

_RESUME_HINT = "--resume continues the run in --out: drop it to start over, or pick another --out"

# The sequence trainers' defaults (posecast.offline.train.cvae_trainer), here so that
# the parser's help and the anomaly AE's checks need not import torch.
_KL_WEIGHT, _HIDDEN, _WINDOW, _BATCH = 1.0, 128, 60, 128


def train_device(name: str) -> str:
    """``--device``: ``auto`` is CUDA when torch sees one, else the CPU; a named
    accelerator that torch cannot see is a configuration error."""
    import torch

    cuda = torch.cuda.is_available()
    if name == "auto":
        return "cuda" if cuda else "cpu"
    if name == "cuda" and not cuda:
        raise config_error("--device cuda: torch sees no CUDA device", "use --device cpu or auto")
    return name


def cmd_train(args: argparse.Namespace) -> int:
    cmd = "train"
    if args.steps is not None:
        at_least("--steps", args.steps, 1, cmd)
    at_least("--threads", args.threads, 1, cmd)
    at_least("--seed", args.seed, 0, cmd)
    finite("--rot-weight", args.rot_weight, cmd)
    finite("--vel-weight", args.vel_weight, cmd)
    finite("--lower-weight", args.lower_weight, cmd, positive=True)
    finite("--kl-weight", args.kl_weight, cmd)
    finite("--budget-min", args.budget_min, cmd)
    for option, value, low in (("--hidden", args.hidden, 64), ("--window", args.window, 2)):
        at_least(option, value, low, cmd)
    at_least("--batch", args.batch, 1, cmd)
    if args.hidden % 64:
        raise config_error(
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
            raise config_error(
                "--layout, --rot-weight, --vel-weight, --lower-weight, --kl-weight, --hidden, "
                "--window, --batch, --budget-min, --device and --no-orientation apply to cvae "
                "and ae only",
                "the anomaly AE reads poses, not trackers: drop those options",
            )
    elif args.network == "ae" and layout != Layout.HMD3_WAIST:
        raise config_error(
            f"the AE ablation exists for the {Layout.HMD3_WAIST} layout only",
            f"drop --layout, or train `posecast train cvae --layout {layout}`",
        )
    elif args.no_orientation and layout == Layout.HMD3_WAIST:
        raise config_error(
            f"--no-orientation: the {layout} features have no orientations",
            f"use it with --layout {Layout.HMD3}",
        )
    check_out_dir("--out", args.out)
    manifest = dataset_manifest(args.data)
    need("train", "torch")
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
            **given(args, _CVAE_FLAGS),
            budget_s=args.budget_min * 60.0,
            device=train_device(args.device),
        )
        need_clips(manifest, args.data, ("train", "val"), cfg.window)
        if args.resume and ckpt.exists():
            check_checkpoint("--resume", ckpt, args.network, str(ls.layout), _RESUME_HINT)
        path = train_cvae(args.data, args.out, model_cfg, cfg, resume=args.resume)
    else:
        from posecast.offline.train.anomaly_trainer import AnomalyTrainConfig, train_anomaly

        acfg = AnomalyTrainConfig(**given(args, ("threads", "seed", "steps")))
        need_clips(manifest, args.data, ("train", "val"), 1)
        if args.resume and ckpt.exists():
            check_checkpoint("--resume", ckpt, "anomaly", hint=_RESUME_HINT)
        path = train_anomaly(args.data, args.out, acfg, resume=args.resume)
    print(f"checkpoint: {path}")
    return 0


# The training settings that `posecast train` passes on under their own names.
_CVAE_FLAGS = ("threads", "seed", "steps", "rot_weight", "vel_weight", "lower_weight",
               "kl_weight", "window", "batch", "no_orientation")  # fmt: skip


def cmd_export(args: argparse.Namespace) -> int:
    jobs: list[tuple[str, Path | None, str, str | None]] = [
        ("--cvae", args.cvae, "cvae", Layout.HMD3_WAIST.value),
        ("--cvae-hmd3", args.cvae_hmd3, "cvae", Layout.HMD3.value),
        ("--cvae-sites", args.cvae_sites, "cvae", Layout.SITES.value),
        ("--ae", args.ae, "ae", Layout.HMD3_WAIST.value),
        ("--anomaly", args.anomaly, "anomaly", None),
    ]
    given = [(opt, path, kind, lay) for opt, path, kind, lay in jobs if path is not None]
    if not given:
        raise config_error(
            "nothing to export",
            "pass one or more of --cvae, --cvae-hmd3, --cvae-sites, --ae, --anomaly",
        )
    check_out_dir("--out", args.out)
    for option, path, _, _ in given:
        if not path.is_file():
            raise hinted(
                ModelError("no such checkpoint file", path=path),
                f"pass the checkpoint.pt that `posecast train` wrote to {option}",
            )
    if args.data is not None:
        need_clips(dataset_manifest(args.data), args.data, ("train",), 1)
    need("train", "torch", "onnx")
    for option, path, kind, layout in given:
        check_checkpoint(option, path, kind, layout)
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


def add_parsers(sub: argparse._SubParsersAction[Any]) -> None:
    """Add ``posecast train`` and ``export`` to ``sub`` (``posecast``'s commands)."""
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
    train.set_defaults(func=cmd_train)

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
    export.set_defaults(func=cmd_export)
