"""``posecast eval`` (the evaluation table, :mod:`posecast.offline.evaluation.runner`,
``docs/evaluation.md``) and ``posecast eval-apps`` (the paper's Table 3, target
hitting and collision avoidance, :mod:`posecast.offline.evaluation.applications`)."""

from __future__ import annotations

import argparse
import contextlib
import sys
from pathlib import Path
from typing import Any

from posecast.cli.common import (
    at_least,
    backend_names,
    check_json_out,
    check_models_dir,
    check_samples,
    config_error,
    dataset_manifest,
    dataset_split,
    finite,
    float_or_off,
    hinted,
    int_list,
    need,
)
from posecast.errors import DataError, ModelError
from posecast.tracking.layouts import Layout


def cmd_eval(args: argparse.Namespace) -> int:
    import json

    from posecast.offline.dataset.split import SPLITS
    from posecast.offline.evaluation.runner import VARIANTS, evaluate, format_table
    from posecast.online.config import ENGINE_SWITCHES, engine_settings
    from posecast.online.engine.config import EngineConfig
    from posecast.online.protocol.messages import MAX_LOOKAHEAD_FRAMES
    from posecast.tracking.layouts import parse_layout
    from posecast.tracking.sites import TrackerSetError

    try:
        layout = parse_layout(args.layout)
    except TrackerSetError as exc:
        raise config_error(
            f"--layout {args.layout!r}: {exc}",
            f"use {Layout.HMD3_WAIST}, {Layout.HMD3} or a tracker set such as "
            "head,left_hand,right_hand,waist,left_foot,right_foot",
        ) from None
    if args.variants is not None:
        variants = [v.strip() for v in args.variants.split(",")]
        unknown = [v for v in variants if v not in VARIANTS]
        if unknown or not variants or len(set(variants)) < len(variants):
            raise config_error(
                f"--variants {args.variants!r}: not a comma-separated subset of the variants",
                f"use some of {', '.join(VARIANTS)}",
            )
    else:
        variants = list(VARIANTS)
        if args.layout != Layout.HMD3_WAIST:
            variants.remove("ae_ik")  # the AE ablation is a 4-point model
    if "ae_ik" in variants and args.layout != Layout.HMD3_WAIST:
        raise config_error(
            f"variant ae_ik exists for the {Layout.HMD3_WAIST} layout only",
            f"drop ae_ik from --variants for --layout {args.layout}",
        )
    if args.data is not None and args.split not in SPLITS:
        raise config_error(f"--split {args.split!r} unknown", f"use one of {', '.join(SPLITS)}")
    check_samples("--samples", [args.samples], "eval")
    finite("--outlier-factor", args.outlier_factor, "eval", positive=True)
    ssi_defaults = EngineConfig()
    latent_scale = ssi_defaults.latent_scale if args.latent_scale is None else args.latent_scale
    finite("--latent-scale", latent_scale, "eval", positive=True)
    home = float_or_off("--home-factor", args.home_factor, ssi_defaults.home_factor)
    (backend,) = backend_names("--backend", args.backend, "eval")
    drift = float_or_off("--ik-max-drift", args.ik_max_drift, ssi_defaults.ik_max_drift_m)
    release = ssi_defaults.ik_release_frames
    wrist = ssi_defaults.wrist_elbow if args.wrist_elbow is None else args.wrist_elbow
    if not 0.0 <= wrist <= 1.0:  # NaN included
        raise config_error(f"--wrist-elbow {wrist} must be a share from 0 to 1", "e.g. 0.75, or 0")
    if args.ik_release_frames is not None:
        at_least("--ik-release-frames", args.ik_release_frames, 1, "eval")
        release = args.ik_release_frames
    lookahead = ssi_defaults.lookahead if args.lookahead is None else args.lookahead
    at_least("--lookahead", lookahead, 0, "eval")
    if lookahead > MAX_LOOKAHEAD_FRAMES:
        raise config_error(
            f"--lookahead {lookahead} must be <= {MAX_LOOKAHEAD_FRAMES}",
            "the paper's is 10; see `posecast eval --help`",
        )
    at_least("--transition-frames", args.transition_frames, 1, "eval")
    switches = {name: getattr(args, name) for name in ENGINE_SWITCHES}  # --no-upper-ik, ...
    engine_cfg = EngineConfig(  # a ConfigError for a bad --samples or --home-factor
        **engine_settings({**switches, "samples": args.samples, "wrist_elbow": wrist}),
        outlier_baseline=args.outlier_baseline,
        outlier_factor=args.outlier_factor,
        ik_max_drift_m=drift,
        ik_release_frames=release,
        latent_scale=latent_scale,
        home_factor=home,
        lookahead=lookahead,
        delayed_emission=args.delayed_emission,
        transition_frames=args.transition_frames,
    )
    check_json_out(args.json)
    check_models_dir(args.models)
    if "baseline_mean_lower_body" in variants:
        from posecast.online.inference.artifact import default_models_dir

        sidecar = (args.models or default_models_dir()) / "cvae_decoder.json"
        meta: Any = None
        with contextlib.suppress(OSError, ValueError):  # unreadable: load_artifact says so
            meta = json.loads(sidecar.read_text("utf-8"))
        if isinstance(meta, dict) and "mean_pose_rot6d" not in meta:
            raise hinted(
                ModelError("the decoder sidecar has no mean_pose_rot6d", path=sidecar),
                "re-export with `posecast export --data DIR`, or leave "
                "baseline_mean_lower_body out of --variants",
            )

    if args.bvh is not None:
        need("data", "scipy")
        from posecast.offline.dataset.prepare import find_bvh_files, process_file
        from posecast.offline.motion.rig import load_rigs

        files = find_bvh_files(args.bvh)
        if not files:
            raise DataError(f"{args.bvh}: no .bvh or .bvh.gz files found")
        rigs = load_rigs()
        clips = [process_file(p, rigs)[1] for p in files]
        fps = 60.0
    else:
        split = dataset_split(args.data, args.split, "evaluate")
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


def cmd_eval_apps(args: argparse.Namespace) -> int:
    import json

    counts = int_list("--samples", args.samples, "eval-apps")
    check_samples("--samples", counts, "eval-apps")
    at_least("--runs", args.runs, 1, "eval-apps")
    at_least("--threads", args.threads, 1, "eval-apps")
    finite("--latent-scale", args.latent_scale, "eval-apps", positive=True)
    (backend,) = backend_names("--backend", args.backend, "eval-apps")
    check_json_out(args.json)
    check_models_dir(args.models)
    dataset_manifest(args.data)
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
        raise config_error(
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


def add_parsers(sub: argparse._SubParsersAction[Any]) -> None:
    """Add ``posecast eval`` and ``eval-apps`` to ``sub`` (``posecast``'s commands)."""
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
        "--lookahead",
        type=int,
        default=None,
        metavar="TAU",
        help="SSI look-ahead tau in frames (default: the served one, 0): how far a "
        "transition's blend has got at the frame of detection, min(tau, T)/T; with "
        "--delayed-emission the engine shows frame n - tau (the paper: --lookahead 10 "
        "--delayed-emission)",
    )
    ev.add_argument(
        "--delayed-emission",
        action="store_true",
        help="emit each pose tau frames after its frame (the paper's look-ahead), not at "
        "once; the present_* metrics then compare it with the truth tau frames later",
    )
    ev.add_argument(
        "--transition-frames",
        type=int,
        default=10,
        metavar="T",
        help="SSI: frames a transition's blend takes (10)",
    )
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
        "--no-planted-toes",
        action="store_true",
        help="cvae_ik, ae_ik and cvae_ik_ssi: a toe in predicted contact near the floor "
        "slides with the network's, not at most 1 m/s (trailing it by up to 4 cm)",
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
    ev.set_defaults(func=cmd_eval)

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
    apps.set_defaults(func=cmd_eval_apps)
