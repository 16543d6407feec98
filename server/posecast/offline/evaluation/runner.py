"""Run the evaluation variants over a list of clips and aggregate their metrics."""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from posecast.body.apart import keep_apart
from posecast.body.clearance import clearance_lift, clip_toe_speed
from posecast.body.hinge import hinge_elbows, hinge_knees
from posecast.body.ik import floor_ik, floor_lift
from posecast.body.leg_ik import senses_legs, solve_legs, tracks_legs
from posecast.body.pelvis import smooth_pelvis_clip
from posecast.body.upper_ik import (
    ease_reach_clip,
    lean_root,
    reach_root,
    solve_upper_body,
    turn_pelvis,
)
from posecast.geometry.rotations import mat2quat, quat2mat
from posecast.offline.dataset.frames import Frames
from posecast.offline.evaluation import metrics as m
from posecast.offline.evaluation import plausibility as pl
from posecast.offline.evaluation.reconstruct import (
    clip_truth,
    contact_ik,
    decode_ae,
    decode_cvae,
    pose_from_rotations,
)
from posecast.online.engine.config import EngineConfig
from posecast.online.engine.ssi import Engine
from posecast.online.engine.types import TrackerFrame
from posecast.online.inference.anomaly import AnomalyScorer
from posecast.online.inference.artifact import load_artifact
from posecast.online.inference.backends import Backend, load_backend
from posecast.skeleton import LOWER_BODY, NUM_ROTATIONS, Joint
from posecast.tracking.features import TrackerSlot
from posecast.tracking.layouts import Layout, PlayerLayout, model_layout, pelvis_from_head, spec
from posecast.tracking.sites import (
    IMU_ACC_BIAS,
    IMU_ACC_NOISE,
    Kind,
    TrackerSet,
    clip_site_features,
    imu_noise,
    site_tracks,
)

VARIANTS = ("cvae_1sample", "cvae_ik", "cvae_ik_ssi", "ae_ik", "baseline_mean_lower_body")
FLAG_KEYS = ("flagged_rate", *(f"flagged_{c}_rate" for c in pl.CATEGORIES))
METRIC_KEYS = (
    "mpjpe_cm",
    "lower_mpjpe_cm",
    "head_pe_cm",
    "hand_pe_cm",
    "hand_rot_err_deg",
    "mpjre_deg",
    "jitter",
    "root_pe_cm",
    *FLAG_KEYS,
    "transitions_per_min",
    "mpjve_cm_s",
    "mpjae_cm_s2",
    "foot_skate_cm_s",
    "ground_penetration_cm",
    "implausible_rate",
)


def _mean_leg_pose(meta: dict[str, Any]) -> np.ndarray | None:
    mean = meta.get("mean_pose_rot6d")
    return None if mean is None else np.asarray(mean, dtype=np.float64).reshape(NUM_ROTATIONS, 6)


@dataclass(frozen=True)
class Tracks:
    """What a clip's player sends, frame by frame, in the engine's rows (4 tracker
    slots, or the ten sites of a tracker set): ``values`` ``(T, rows, 3)`` positions
    (an inertial site's acceleration), ``quat`` ``(T, rows, 4)``; and the network's
    input ``features`` ``(T, F)``. Rows 0-3 are head, hands and waist either way."""

    values: np.ndarray
    quat: np.ndarray
    features: np.ndarray


def clip_tracks(
    fr: Frames,
    fps: float,
    layout: PlayerLayout,
    seed: int = 0,
    acc_noise: float = IMU_ACC_NOISE,
    acc_bias: float = IMU_ACC_BIAS,
    truth: tuple[np.ndarray, np.ndarray] | None = None,
) -> Tracks:
    """The trackers of ``layout`` on a clip. A tracker set's sites sit on their joints of
    the true pose (:func:`~posecast.tracking.sites.site_tracks`; ``truth``: the clip's
    world rotations and positions when the caller has them already); its inertial
    sites' accelerations get the training's sensor noise (``acc_noise`` white,
    ``acc_bias`` held over the clip, m/s^2), drawn from ``seed``."""
    if not isinstance(layout, TrackerSet):
        ls = spec(layout)
        features = (
            fr["features"]
            if ls.layout is Layout.HMD3_WAIST
            else ls.clip_features(fr["tracker_pos"], fr["tracker_quat"], fps)
        )
        return Tracks(
            fr["tracker_pos"].astype(np.float64),
            fr["tracker_quat"].astype(np.float64),
            np.asarray(features, np.float32),
        )
    kinds = layout.kinds()
    true_mat, true_pos = truth or clip_truth(fr)
    pos, quat, acc = site_tracks(true_mat, true_pos, fps)
    acc = acc + imu_noise(np.random.default_rng(seed), len(acc), acc_noise, acc_bias)
    values = np.where((kinds == Kind.INERTIAL)[:, None], acc, pos)
    features = clip_site_features(pos, quat, acc, kinds, fps).astype(np.float32)
    return Tracks(values, quat, features)


def evaluate(
    clips: Sequence[Frames],
    fps: float,
    variants: Sequence[str] = VARIANTS,
    models_dir: str | Path | None = None,
    log: Callable[[str], None] | None = None,
    engine_cfg: EngineConfig | None = None,
    layout: PlayerLayout | str = Layout.HMD3_WAIST,
    backend: str = "native",
) -> dict[str, Any]:
    """Metrics per variant over ``clips`` (each a :data:`Frames` dict with ground truth),
    for the model of tracker ``layout`` (a named layout, or a
    :class:`~posecast.tracking.sites.TrackerSet` for the one model of every set). The
    full method (``cvae_ik_ssi``) runs the SSI engine on ``backend`` (the report's
    ``backend`` names the one that ran); the other variants and the scores behind
    ``implausible_rate`` run the ONNX models.

    ``baseline_mean_lower_body`` takes the true upper body and pelvis whatever the
    layout, so only its lower-body numbers are a floor to beat.

    ``cvae_ik`` and ``ae_ik`` are what the server would stream without SSI: the
    pelvis smoothing (``engine_cfg.pelvis_smoothing``), contact IK, the floor pass
    (``engine_cfg.floor_ik``; with it the swing clearance, ``swing_clearance``), the
    knee hinge (``knee_hinge``) and (when ``engine_cfg.upper_body_ik``, the default)
    the engine's upper-body pass (its elbow hint at ``wrist_elbow``; a guessed pelvis
    first moved toward out-of-reach trackers, ``hand_reach``, before the contact IK as
    the engine does), then the elbow hinge (``elbow_hinge``), so that ``cvae_ik_ssi``
    against ``cvae_ik`` measures SSI alone.
    ``cvae_1sample`` is the network's raw pose.
    """
    player_layout = layout if isinstance(layout, TrackerSet) else Layout(layout)
    ls = spec(model_layout(player_layout))
    tracker_set = player_layout if isinstance(player_layout, TrackerSet) else None
    dec = load_artifact(ls.decoder, models_dir)
    scorer = AnomalyScorer(load_artifact(ls.anomaly, models_dir))
    if "ae_ik" in variants and ls.layout is not Layout.HMD3_WAIST:
        raise ValueError("the AE ablation (ae_ik) exists for the 4-point layout only")
    ae = load_artifact("ae_step", models_dir) if "ae_ik" in variants else None
    latent = int(dec.meta["model_config"]["latent"])
    base = dec if ls.layout is Layout.HMD3_WAIST else load_artifact("cvae_decoder", models_dir)
    mean_pose = _mean_leg_pose(base.meta)
    leg_rot = [int(j) - 1 for j in LOWER_BODY]  # rotation rows of the leg joints
    results: dict[str, Any] = {}
    truth = [clip_truth(fr) for fr in clips]
    tracks = [
        clip_tracks(fr, fps, player_layout, seed=i, truth=truth[i]) for i, fr in enumerate(clips)
    ]
    # The pelvis of a single-sample variant: the waist tracker's, or the decoder's own.
    root_from_waist = tracker_set.tracks_waist if tracker_set is not None else not ls.predicts_root
    engine_cfg = engine_cfg or EngineConfig()
    # A guessed pelvis leans toward the headset, as the engine's does; not that of a set
    # that senses its legs, which keeps its hips as they are.
    legs_sensed = tracker_set is not None and bool(senses_legs(tracker_set.kinds()[None])[0])
    lean = not root_from_waist and not legs_sensed and engine_cfg.leans
    ssi_backend = (
        load_backend(backend, ls.layout, models_dir, cfg=engine_cfg)
        if "cvae_ik_ssi" in variants
        else None
    )
    for name in variants:
        acc, t0 = m.Accumulator(), time.perf_counter()
        ssi: list[tuple[np.ndarray, np.ndarray, int]] = []
        transitions = 0
        if name == "cvae_ik_ssi":
            assert ssi_backend is not None
            ssi = run_ssi(ssi_backend, tracks, engine_cfg, tracker_set)
        for ci, fr in enumerate(clips):
            tr = tracks[ci]
            feats = tr.features
            # The true pelvis (baseline_mean_lower_body), or the waist tracker's.
            root_mat = quat2mat(fr["tracker_quat"][:, TrackerSlot.WAIST].astype(np.float64))
            root_pos = fr["tracker_pos"][:, TrackerSlot.WAIST].astype(np.float64)
            if name == "cvae_ik_ssi":
                wm, wp, n_trans = ssi[ci]
                transitions += n_trans
            elif name.startswith("cvae"):
                rot, con, root = decode_cvae(dec, feats, np.zeros(latent, np.float32))
                if root is not None and not root_from_waist:
                    head_pos = tr.values[:, TrackerSlot.HEAD]
                    head_quat = tr.quat[:, TrackerSlot.HEAD]
                    root_mat, root_pos = pelvis_from_head(root, head_pos, head_quat)
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
                if name.endswith("_ik") and engine_cfg.pelvis_smoothing and engine_cfg.lookahead:
                    root_mat, root_pos = smooth_pelvis_clip(root_mat, root_pos)
                if name.endswith("_ik") and lean:
                    _, near = pose_from_rotations(rot, root_mat, root_pos)
                    turn = lean_root(root_pos, near[:, Joint.HEAD], tr.values[:, TrackerSlot.HEAD])
                    leant, turned = turn_pelvis(rot, root_mat, turn)
                    rot, root_mat = np.asarray(leant), np.asarray(turned, np.float64)
                wm, wp = pose_from_rotations(rot, root_mat, root_pos)
                if name.endswith("_ik") and not root_from_waist and engine_cfg.reaches:
                    span = None if engine_cfg.torso_span and not legs_sensed else 0.0
                    wp = wp + ease_reach_clip(reach_root(wp, tr.values, span))[:, None]
                if name.endswith("_ik"):
                    net_mat, net_pos = wm.copy(), wp.copy()
                    contact_ik(wm, wp, con, engine_cfg.ik_release_frames, engine_cfg.ik_max_drift_m)
                    if engine_cfg.legs_apart:
                        keep_apart(wm, wp, net_mat, net_pos)
                    if engine_cfg.floor_ik:
                        lift = floor_lift(wp)
                        if engine_cfg.swing_clearance:
                            speed = clip_toe_speed(wp, fps)
                            lift = np.maximum(lift, clearance_lift(wp, speed))
                        floor_ik(wm, wp, lift=lift)
                    if engine_cfg.upper_body_ik and tracker_set is not None:
                        wm, wp = _legs(wm, wp, tr, tracker_set)
                    if engine_cfg.knee_hinge:
                        hinge_knees(wm, wp)
                    if engine_cfg.upper_body_ik:
                        wm, wp = _upper_body(
                            wm, wp, tr, not root_from_waist, engine_cfg.wrist_elbow
                        )
                    if engine_cfg.elbow_hinge:
                        hinge_elbows(wm, wp)
            gt_mat, gt = truth[ci]
            acc.add("mpjpe_cm", m.mpjpe(wp, gt))
            acc.add("lower_mpjpe_cm", m.lower_mpjpe(wp, gt))
            acc.add("mpjve_cm_s", m.mpjve(wp, gt, fps))
            acc.add("mpjae_cm_s2", m.mpjae(wp, gt, fps))
            acc.add("foot_skate_cm_s", m.foot_skate(wp, fr["contacts"], fps))
            acc.add("ground_penetration_cm", m.ground_penetration(wp))
            # Each pose is scored with its own pelvis (the waist tracker's for 4 points).
            scores = scorer.score_mats(wp, wp[:, 0], wm[:, 0])
            acc.add("implausible_rate", m.implausible(scores, scorer.threshold_m))
            acc.add("root_pe_cm", m.root_pe(wp, gt))
            acc.add("hand_pe_cm", m.hand_pe(wp, gt))
            acc.add("head_pe_cm", m.head_pe(wp, gt))
            acc.add("hand_rot_err_deg", m.hand_rot_err(wm, gt_mat))
            acc.add("mpjre_deg", m.mpjre(wm, gt_mat))
            acc.add("jitter", m.jitter(wp, fps))
            for key, pair in m.flag_rates(pl.flags(wm, wp, fps)).items():
                acc.add(key, pair)
        means = acc.means()
        if name == "cvae_ik_ssi":
            minutes = sum(len(fr["features"]) for fr in clips) / fps / 60.0
            means["transitions_per_min"] = transitions / minutes
        res: dict[str, Any] = {k: round(v, 4) for k, v in means.items()}
        res["seconds"] = round(time.perf_counter() - t0, 2)
        results[name] = res
        if log:
            log(f"{name}: {res['seconds']:.1f} s")
    gt_acc = m.Accumulator()
    for gt_mat, gt in truth:
        gt_acc.add("jitter", m.jitter(gt, fps))
        for key, pair in m.flag_rates(pl.flags(gt_mat, gt, fps)).items():
            gt_acc.add(key, pair)
    ground_truth = {k: round(v, 4) for k, v in gt_acc.means().items()}
    return {
        "layout": str(player_layout),
        "backend": ssi_backend.name if ssi_backend is not None else None,
        "variants": results,
        "clips": len(clips),
        "frames": int(sum(len(c["features"]) for c in clips)),
        "fps": fps,
        "implausible_threshold_m": scorer.threshold_m,
        "ground_truth": ground_truth,
    }


def _upper_body(
    wm: np.ndarray, wp: np.ndarray, tr: Tracks, free_root: bool, wrist_share: float
) -> tuple[np.ndarray, np.ndarray]:
    """The engine's upper-body pass over a clip: head and hands onto the clip's trackers
    (``free_root``: the pelvis is the decoder's, which may follow the headset;
    ``wrist_share``: of the elbows' hints, the controllers' share)."""
    slots = len(TrackerSlot)
    free = np.full(len(wp), free_root)
    pos, quat, _ = solve_upper_body(
        wp, mat2quat(wm), tr.values[:, :slots], tr.quat[:, :slots], free, wrist_share
    )
    return quat2mat(quat.astype(np.float64)), pos.astype(np.float64)


def _legs(
    wm: np.ndarray, wp: np.ndarray, tr: Tracks, tracker_set: TrackerSet
) -> tuple[np.ndarray, np.ndarray]:
    """The engine's lower-body pass over a clip: feet and knees onto a tracker set's
    positional trackers (a no-op for a set without them)."""
    per_site = tracker_set.kinds()
    if not tracks_legs(per_site[None]).any():
        return wm, wp
    kinds = np.broadcast_to(per_site, (len(wp), *per_site.shape))
    pos, quat, _ = solve_legs(wp, mat2quat(wm), tr.values, tr.quat, kinds)
    return quat2mat(quat.astype(np.float64)), pos.astype(np.float64)


def run_ssi(
    backend: Backend,
    clips: Sequence[Tracks],
    cfg: EngineConfig,
    tracker_set: TrackerSet | None = None,
) -> list[tuple[np.ndarray, np.ndarray, int]]:
    """The full method: every clip's trackers as one player of one engine on
    ``backend`` (every player on ``tracker_set``, for the sites model), all stepped
    together.

    Returns per clip the emitted world rotations ``(T, 19, 3, 3)`` and positions
    ``(T, 19, 3)``, aligned with the input frames (the engine's ``tau``-frame delay
    undone by ``seq``), and the number of transitions.
    """
    engine = Engine(
        backend.decoder, backend.pool, cfg, capacity=len(clips), backend_name=backend.name
    )
    for i in range(len(clips)):
        engine.add_player(str(i), seed=i, tracker_set=tracker_set)
    out = [np.full((len(tr.values), 19, 3), np.nan, np.float32) for tr in clips]
    rots = [np.full((len(tr.values), 19, 4), np.nan, np.float32) for tr in clips]
    done: dict[int, int] = {}
    longest = max(len(tr.values) for tr in clips)
    for t in range(longest + cfg.lookahead):
        for i, tr in enumerate(clips):
            if t < len(tr.values):
                engine.push(str(i), TrackerFrame(t, tr.values[t], tr.quat[t]))
        for pose in engine.tick().poses:
            i = int(pose.player)
            if not pose.held and 0 <= pose.seq < len(out[i]):
                out[i][pose.seq] = pose.positions
                rots[i][pose.seq] = pose.rotations
        for i, tr in enumerate(clips):
            if i not in done and t + 1 >= len(tr.values) + cfg.lookahead:
                done[i] = engine.transitions(str(i))
                engine.remove_player(str(i))
    if any(np.isnan(o).any() for o in out):
        raise RuntimeError("the engine skipped frames")  # a bug, never bad data
    return [
        (quat2mat(r.astype(np.float64)), o.astype(np.float64), done[i])
        for i, (r, o) in enumerate(zip(rots, out, strict=True))
    ]


def format_table(report: dict[str, Any]) -> str:
    """The console table of ``posecast eval``: a metric per row, a variant per column
    (and the ground truth's own figures), so that the long metric names fit; a figure
    a variant does not have is ``-``. ``--json`` keeps the report itself."""
    columns = [(name, res) for name, res in report["variants"].items()]
    gt = report.get("ground_truth") or {}
    if gt:
        columns.append(("ground_truth", gt))
    rows = [(k, [res.get(k) for _, res in columns]) for k in METRIC_KEYS]
    rows.append(("seconds", [res.get("seconds") for _, res in columns]))

    def cell(x: float | None, digits: int) -> str:
        return "-" if x is None else f"{x:.{digits}f}"

    cells = [(k, [cell(x, 1 if k == "seconds" else 3) for x in xs]) for k, xs in rows]
    first = max(len("metric"), *(len(k) for k, _ in cells))
    widths = [
        max(len(name), *(len(row[i]) for _, row in cells)) for i, (name, _) in enumerate(columns)
    ]

    def line(label: str, texts: list[str]) -> str:
        return f"{label:<{first}}" + "".join(
            f"  {t:>{w}}" for t, w in zip(texts, widths, strict=True)
        )

    title = f"layout {report.get('layout', Layout.HMD3_WAIST)}"
    if report.get("backend"):
        title += f", SSI on backend {report['backend']}"
    lines = [title, line("metric", [name for name, _ in columns])]
    lines += [line(k, row) for k, row in cells]
    return "\n".join(lines)
