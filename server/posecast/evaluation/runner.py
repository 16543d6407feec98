"""Run the evaluation variants over a list of clips and aggregate their metrics."""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from posecast.dataset.frames import Frames
from posecast.engine.anomaly import AnomalyScorer
from posecast.engine.config import EngineConfig
from posecast.engine.engine import Engine, TrackerFrame
from posecast.evaluation import metrics as m
from posecast.evaluation.reconstruct import contact_ik, decode_ae, decode_cvae, pose_from_rotations
from posecast.inference.artifact import Artifact, load_artifact
from posecast.skeleton import LOWER_BODY, NUM_ROTATIONS
from posecast.tracking import TrackerSlot

VARIANTS = ("cvae_1sample", "cvae_ik", "cvae_ik_ssi", "ae_ik", "baseline_mean_lower_body")
METRIC_KEYS = (
    "mpjpe_cm",
    "lower_mpjpe_cm",
    "mpjve_cm_s",
    "mpjae_cm_s2",
    "foot_skate_cm_s",
    "ground_penetration_cm",
    "implausible_rate",
    "transitions_per_min",
)


def _mean_leg_pose(meta: dict[str, Any]) -> np.ndarray | None:
    mean = meta.get("mean_pose_rot6d")
    return None if mean is None else np.asarray(mean, dtype=np.float64).reshape(NUM_ROTATIONS, 6)


def evaluate(
    clips: Sequence[Frames],
    fps: float,
    variants: Sequence[str] = VARIANTS,
    models_dir: str | Path | None = None,
    log: Callable[[str], None] | None = None,
    engine_cfg: EngineConfig | None = None,
) -> dict[str, Any]:
    """Metrics per variant over ``clips`` (each a :data:`Frames` dict with ground truth)."""
    dec = load_artifact("cvae_decoder", models_dir)
    scorer = AnomalyScorer(load_artifact("anomaly", models_dir))
    ae = load_artifact("ae_step", models_dir) if "ae_ik" in variants else None
    latent = int(dec.meta["model_config"]["latent"])
    mean_pose = _mean_leg_pose(dec.meta)
    leg_rot = [int(j) - 1 for j in LOWER_BODY]  # rotation rows of the leg joints
    results: dict[str, Any] = {}
    for name in variants:
        acc, t0 = m.Accumulator(), time.perf_counter()
        ssi: list[tuple[np.ndarray, int]] = []
        transitions = 0
        if name == "cvae_ik_ssi":
            ssi = run_ssi(dec, scorer, clips, engine_cfg or EngineConfig())
        for ci, fr in enumerate(clips):
            feats = fr["features"].astype(np.float32)
            wpos = fr["tracker_pos"][:, TrackerSlot.WAIST].astype(np.float64)
            wquat = fr["tracker_quat"][:, TrackerSlot.WAIST].astype(np.float64)
            if name == "cvae_ik_ssi":
                wp, n_trans = ssi[ci]
                transitions += n_trans
            elif name.startswith("cvae"):
                rot, con = decode_cvae(dec, feats, np.zeros(latent, np.float32))
            elif name == "ae_ik":
                assert ae is not None
                rot, con = decode_ae(ae, feats)
            elif name == "baseline_mean_lower_body":
                if mean_pose is None:
                    raise ValueError("the decoder sidecar has no mean_pose_rot6d")
                rot = fr["rot6d"].astype(np.float64).copy()  # upper body: ground truth
                rot[:, leg_rot] = mean_pose[leg_rot]
                con = np.zeros((len(feats), 2))
            else:
                raise ValueError(f"unknown variant {name!r}")
            if name != "cvae_ik_ssi":
                wm, wp = pose_from_rotations(rot, wpos, wquat)
                if name.endswith("_ik"):
                    contact_ik(wm, wp, con)
            gt = fr["positions"].astype(np.float64)
            acc.add("mpjpe_cm", m.mpjpe(wp, gt))
            acc.add("lower_mpjpe_cm", m.lower_mpjpe(wp, gt))
            acc.add("mpjve_cm_s", m.mpjve(wp, gt, fps))
            acc.add("mpjae_cm_s2", m.mpjae(wp, gt, fps))
            acc.add("foot_skate_cm_s", m.foot_skate(wp, fr["contacts"], fps))
            acc.add("ground_penetration_cm", m.ground_penetration(wp))
            acc.add(
                "implausible_rate", m.implausible(scorer.score(wp, wpos, wquat), scorer.threshold_m)
            )
        means = acc.means()
        if name == "cvae_ik_ssi":
            minutes = sum(len(fr["features"]) for fr in clips) / fps / 60.0
            means["transitions_per_min"] = transitions / minutes
        res: dict[str, Any] = {k: round(v, 4) for k, v in means.items()}
        res["seconds"] = round(time.perf_counter() - t0, 2)
        results[name] = res
        if log:
            log(f"{name}: {res}")
    return {
        "variants": results,
        "clips": len(clips),
        "frames": int(sum(len(c["features"]) for c in clips)),
        "fps": fps,
        "implausible_threshold_m": scorer.threshold_m,
    }


def run_ssi(
    dec: Artifact, scorer: AnomalyScorer, clips: Sequence[Frames], cfg: EngineConfig
) -> list[tuple[np.ndarray, int]]:
    """The full method: every clip as one player of one engine, all stepped together.

    Returns per clip the emitted world positions ``(T, 19, 3)``, aligned with the
    input frames (the engine's ``tau``-frame delay undone by ``seq``), and the number
    of transitions.
    """
    engine = Engine(dec, scorer, cfg, capacity=len(clips))
    for i in range(len(clips)):
        engine.add_player(str(i), seed=i)
    out = [np.full((len(fr["features"]), 19, 3), np.nan, np.float32) for fr in clips]
    done: dict[int, int] = {}
    longest = max(len(fr["features"]) for fr in clips)
    for t in range(longest + cfg.lookahead):
        for i, fr in enumerate(clips):
            if t < len(fr["features"]):
                pos, quat = fr["tracker_pos"][t], fr["tracker_quat"][t]
                engine.push(
                    str(i), TrackerFrame(t, pos.astype(np.float64), quat.astype(np.float64))
                )
        for pose in engine.tick().poses:
            i = int(pose.player)
            if not pose.held and 0 <= pose.seq < len(out[i]):
                out[i][pose.seq] = pose.positions
        for i, fr in enumerate(clips):
            if i not in done and t + 1 >= len(fr["features"]) + cfg.lookahead:
                done[i] = engine.transitions(str(i))
                engine.remove_player(str(i))
    if any(np.isnan(o).any() for o in out):
        raise RuntimeError("the engine skipped frames")  # a bug, never bad data
    return [(o.astype(np.float64), done[i]) for i, o in enumerate(out)]


def format_table(report: dict[str, Any]) -> str:
    head = f"{'variant':26s}" + "".join(f"{k:>22s}" for k in METRIC_KEYS) + f"{'seconds':>9s}"
    lines = [head]
    for name, res in report["variants"].items():
        row = f"{name:26s}" + "".join(f"{res.get(k, float('nan')):22.3f}" for k in METRIC_KEYS)
        lines.append(row + f"{res.get('seconds', 0):9.1f}")
    return "\n".join(lines)
