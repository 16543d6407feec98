"""``posecast train cvae`` and ``posecast train ae``: the GRU CVAE and its AE ablation.

Loss (paper Sec. 3.1): ``MSE(FK positions, cm^2) + lambda * KL + gamma * BCE(contacts)``.
The paper gives lambda = 5, gamma = 0.1 without the scale of its MSE. With positions in
centimetres the MSE is about 30 early on; lambda = 1 corresponds to a Gaussian decoder
with sigma of about 5 cm per coordinate (2 sigma^2 / 57 coordinates), and gamma = 5
keeps the contact head at about a tenth of the loss. See docs/model-card.md.
"""

from __future__ import annotations

import json
import time
from dataclasses import asdict, dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np
import torch

from posecast.geometry.torch_ops import r6d2mat
from posecast.offline.dataset.augment import Augmentation
from posecast.offline.nets.cvae import CVAE, CVAEConfig
from posecast.offline.train.checkpoint import resume_into, save_training, start_run
from posecast.offline.train.data import Normalisation, TrainArrays, compose_sites, load_train_val
from posecast.offline.train.losses import PoseFK, position_mse_cm2, split_root, velocity_mse_cm2
from posecast.offline.train.masks import add_inertial_noise, cycle_table_kinds, sample_kinds
from posecast.skeleton import LOWER_BODY, NUM_JOINTS
from posecast.tracking.layouts import spec
from posecast.tracking.sites import IMU_ACC_BIAS, IMU_ACC_NOISE, SITE_ROW, Kind, Site


@dataclass(frozen=True)
class CVAETrainConfig:
    steps: int = 12000
    batch: int = 128
    window: int = 60
    lr: float = 2e-4  # paper Sec. 4.3
    decay_from: float = 0.7  # linear decay to lr * final_lr_ratio over the last 30 %
    final_lr_ratio: float = 0.1
    kl_weight: float = 1.0
    contact_weight: float = 5.0
    # Squared Frobenius distance of the local rotations to the truth (pelvis included
    # when predicted). Positions alone leave each bone's twist free: without this term
    # the rotations are right only where they move a joint. 0 for the shipped 4-point
    # model (trained before it existed), 10 for the headset-only one (docs/model-card.md).
    rot_weight: float = 0.0
    # Squared error of the joints' frame-to-frame displacement, cm^2 per frame: the
    # network's own frame-to-frame noise (jitter) costs here and nowhere else, since
    # every other term scores each frame alone. 0 for the weights trained before it.
    vel_weight: float = 0.0
    # Weight of the leg joints (posecast.skeleton.LOWER_BODY) in the position term against
    # 1 for the others, the term normalised to the mean weight: the serving passes put
    # head and hands on their trackers, so the network's legs are most of what is shown
    # of its positions. 1 for the shipped weights.
    lower_weight: float = 1.0
    # Ablation (docs/evaluation.md): zero the headset-only model's orientation inputs,
    # leaving it the positions and velocities a 4-point model reads.
    no_orientation: bool = False
    # The one model of every tracker set (layout ``sites``): sensor noise on the
    # synthetic IMU accelerations, m/s^2 (docs/model-card.md), and the share of windows
    # that take one of the evaluation table's sets (posecast.offline.train.masks).
    imu_acc_noise: float = IMU_ACC_NOISE
    imu_acc_bias: float = IMU_ACC_BIAS
    table_share: float = 0.25
    seed: int = 0
    log_every: int = 100
    val_every: int = 1000
    ckpt_every: int = 500
    threads: int = 2
    # "cpu", "cuda" or any torch device string; the CLI's "auto" resolves to "cuda" when
    # torch sees one. Nothing requires an accelerator: the default is the CPU.
    device: str = "cpu"
    # Wall-time budget in seconds (0: none), data loading included: until the learning
    # rate starts to decay, each log re-plans ``steps`` (never above the given number)
    # so that the run, its decay included, ends inside the budget at the speed measured
    # since the last log. The checkpoint's ``train_config`` keeps the steps it ran.
    budget_s: float = 0.0
    mirror: bool = True
    speeds: tuple[float, ...] = (0.8, 1.0, 1.2)
    bone_scale: tuple[float, float] = (0.92, 1.08)
    bone_jitter: float = 0.03

    def augmentation(self) -> Augmentation:
        return Augmentation(self.mirror, self.speeds, self.bone_scale, self.bone_jitter)


def _batch(
    arr: TrainArrays,
    starts: np.ndarray,
    norm: Normalisation,
    T: int,
    kinds: np.ndarray | None = None,
    noise: tuple[np.random.Generator, float, float] | None = None,
    device: str = "cpu",
) -> dict[str, torch.Tensor]:
    """One batch of windows on ``device``; ``kinds (B, 10)``: each window's tracker set
    (layout ``sites``), ``noise``: the generator and IMU noise levels to add."""
    idx = starts[:, None] + np.arange(T)[None, :]  # (B, T)
    raw = arr.features[idx]
    extra: dict[str, torch.Tensor] = {}
    if arr.features_imu is not None:
        if kinds is None:
            raise ValueError("a tracker-set batch needs each window's kinds")
        raw = compose_sites(raw, arr.features_imu[idx], kinds)
        if noise is not None:
            add_inertial_noise(raw, kinds, *noise)
        extra["waist_tracked"] = torch.from_numpy(kinds[:, SITE_ROW[Site.WAIST]] == Kind.POSITIONAL)
    feats = (raw - norm.feat_mean) / norm.feat_std
    pos = arr.local_pos[idx]  # (B, T, 19, 3)
    pose_in = (pos.reshape(*idx.shape, 57) - norm.pose_mean) / norm.pose_std
    out = {
        **extra,
        "x": torch.from_numpy(np.ascontiguousarray(feats, dtype=np.float32)),
        "pose_in": torch.from_numpy(np.ascontiguousarray(pose_in, dtype=np.float32)),
        "pos": torch.from_numpy(pos),
        "root_mat": torch.from_numpy(arr.root_mat[idx]),
        "contacts": torch.from_numpy(arr.contacts[idx]),
        "rot6d": torch.from_numpy(arr.rot6d[idx]),
    }
    if device == "cpu":
        return out
    return {k: v.to(device, non_blocking=True) for k, v in out.items()}


def _losses(
    model: CVAE, fk: PoseFK, b: dict[str, torch.Tensor], cfg: CVAETrainConfig, sample: bool = True
) -> dict[str, torch.Tensor]:
    out, logits, kl = model(b["x"], b["pose_in"], sample=sample)
    rot, root_mat, root_pos = _roots(out, b)
    pred = fk(rot, root_mat, root_pos)  # (B, T, 19, 3)
    mse = position_mse_cm2(pred, b["pos"], joint_weights(cfg.lower_weight, pred))
    bce = torch.nn.functional.binary_cross_entropy_with_logits(logits, b["contacts"])
    klm = kl.mean()
    total = mse + cfg.kl_weight * klm + cfg.contact_weight * bce
    parts = {"mse_cm2": mse, "kl": klm, "bce": bce}
    if cfg.rot_weight > 0:
        pred_m = r6d2mat(rot.reshape(*rot.shape[:-1], 18, 6))
        true_m = r6d2mat(b["rot6d"])
        if out.shape[-1] > 108:  # the predicted pelvis counts as a 19th joint
            pred_m = torch.cat([root_mat.unsqueeze(-3), pred_m], dim=-3)
            true_m = torch.cat([b["root_mat"].unsqueeze(-3), true_m], dim=-3)
        rot_err = (pred_m - true_m).pow(2).sum(dim=(-2, -1)).mean()
        total = total + cfg.rot_weight * rot_err
        parts["rot_frob2"] = rot_err
    if cfg.vel_weight > 0:
        vel = velocity_mse_cm2(pred, b["pos"])
        total = total + cfg.vel_weight * vel
        parts["vel_mse_cm2"] = vel
    mpjpe = ((pred - b["pos"]).norm(dim=-1).mean() * 100.0).detach()
    return {"loss": total, **parts, "mpjpe_cm": mpjpe}


def joint_weights(lower_weight: float, like: torch.Tensor) -> torch.Tensor | None:
    """Per-joint weights ``(19,)`` of the position term: ``lower_weight`` for the legs,
    1 elsewhere, or ``None`` when all are 1."""
    if lower_weight == 1.0:
        return None
    w = torch.ones(NUM_JOINTS, dtype=like.dtype, device=like.device)
    w[[int(j) for j in LOWER_BODY]] = lower_weight
    return w


def _roots(
    out: torch.Tensor, b: dict[str, torch.Tensor]
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """:func:`split_root`, and for a tracker-set batch the true pelvis (the waist
    tracker's, as served) in the windows whose set tracks the waist's position."""
    rot, root_mat, root_pos = split_root(out, b["root_mat"], b["pos"][..., 0, :])
    if "waist_tracked" in b:
        w = b["waist_tracked"][:, None]  # (B, 1)
        root_mat = torch.where(w[..., None, None], b["root_mat"], root_mat)
        root_pos = torch.where(w[..., None], b["pos"][..., 0, :], root_pos)
    return rot, root_mat, root_pos


def train_cvae(
    data_dir: str | Path,
    out_dir: str | Path,
    model_cfg: CVAEConfig,
    cfg: CVAETrainConfig,
    resume: bool = False,
    log: Any = print,
) -> Path:
    """Train, checkpointing to ``out_dir/checkpoint.pt``; returns the checkpoint path."""
    ckpt_path = start_run(out_dir, cfg.threads)
    t0 = time.perf_counter()
    manifest, train, val = load_train_val(data_dir, cfg.augmentation(), cfg.seed, model_cfg.layout)
    if cfg.no_orientation:
        cols = [i for i, n in enumerate(spec(model_cfg.layout).feature_names) if ".r" in n]
        if not cols:
            raise ValueError(f"layout {model_cfg.layout} has no orientation features")
        train.features[:, cols] = 0.0
        val.features[:, cols] = 0.0
    log(
        f"data: {train.n_frames} train frames after augmentation, {val.n_frames} val frames "
        f"({time.perf_counter() - t0:.1f} s)"
    )
    torch.manual_seed(cfg.seed)
    dev = cfg.device
    model = CVAE(model_cfg).to(dev)
    fk = PoseFK().to(dev)
    opt = torch.optim.Adam(model.parameters(), lr=cfg.lr, betas=(0.9, 0.999))
    norm = Normalisation.fit(train)
    step = 0
    history: list[dict[str, float]] = []
    elapsed = 0.0
    if resume and ckpt_path.exists():
        state, step, history, elapsed = resume_into(ckpt_path, model, opt)
        norm = Normalisation.from_dict(state["norm"])
        torch.set_rng_state(state["torch_rng"])
        log(f"resumed from {ckpt_path} at step {step}")
    rng = np.random.default_rng(cfg.seed + step)
    starts = train.window_starts(cfg.window)
    val_starts = val.window_starts(cfg.window)[:: max(1, cfg.window // 2)]
    sites = train.features_imu is not None

    def save() -> None:
        save_training(
            ckpt_path,
            "ae" if model_cfg.deterministic else "cvae",
            model,
            opt,
            (model_cfg.to_dict(), asdict(cfg)),
            norm.to_dict(),
            (step, history, elapsed),
            (data_dir, manifest, train.n_frames),
            {"torch_rng": torch.get_rng_state()},
        )

    t_log = time.perf_counter()
    frames_since = 0
    asked = cfg.steps  # a budget's plan may lower the steps, and raise them back to this
    model.train()
    while step < cfg.steps:
        for group in opt.param_groups:
            group["lr"] = learning_rate(cfg, step)
        kinds = sample_kinds(rng, cfg.batch, cfg.table_share) if sites else None
        noise = (rng, cfg.imu_acc_noise, cfg.imu_acc_bias)
        b = _batch(train, rng.choice(starts, cfg.batch), norm, cfg.window, kinds, noise, dev)
        parts = _losses(model, fk, b, cfg)
        opt.zero_grad(set_to_none=True)
        parts["loss"].backward()  # type: ignore[no-untyped-call]
        torch.nn.utils.clip_grad_norm_(model.parameters(), 1.0)
        opt.step()
        step += 1
        frames_since += cfg.batch * cfg.window
        if step % cfg.log_every == 0 or step == cfg.steps:
            dt = time.perf_counter() - t_log
            elapsed += dt
            rec = {k: float(v.detach()) for k, v in parts.items()} | {
                "step": step,
                "seconds": elapsed,
            }
            rec["frames_per_s"] = frames_since / dt
            if cfg.budget_s > 0 and step < cfg.decay_from * cfg.steps:
                spent = time.perf_counter() - t0
                planned = plan_steps(cfg, step, spent, dt / cfg.log_every, asked)
                if planned != cfg.steps:
                    cfg = replace(cfg, steps=planned)
                    rec["planned_steps"] = planned
            if step % cfg.val_every == 0 or step == cfg.steps:
                rec["val_mpjpe_cm"] = evaluate_val(model, fk, val, val_starts, norm, cfg)
                model.train()
            history.append(rec)
            log(json.dumps({k: round(v, 4) if isinstance(v, float) else v for k, v in rec.items()}))
            t_log = time.perf_counter()
            frames_since = 0
        if step % cfg.ckpt_every == 0 or step == cfg.steps:
            save()
    return ckpt_path


def plan_steps(
    cfg: CVAETrainConfig, step: int, spent_s: float, step_s: float, most: int | None = None
) -> int:
    """The steps a run with ``cfg.budget_s`` can finish: ``step`` done after ``spent_s``
    seconds, ``step_s`` seconds a step lately; 10 % of what is left is kept for the
    validation passes and checkpoints. Never more than ``most`` (default ``cfg.steps``:
    the steps asked for, which an earlier, slower plan may have lowered), never fewer
    than ``step + 1``."""
    left = max(0.0, cfg.budget_s - spent_s) * 0.9
    cap = cfg.steps if most is None else most
    return max(step + 1, min(cap, step + int(left / max(step_s, 1e-9))))


def learning_rate(cfg: CVAETrainConfig, step: int) -> float:
    """Constant, then linear decay to ``lr * final_lr_ratio`` from ``decay_from * steps``.

    Computed from the step alone, so a resumed run with more steps continues smoothly.
    """
    start = cfg.decay_from * cfg.steps
    if step < start:
        return cfg.lr
    frac = min(1.0, (step - start) / max(1.0, cfg.steps - start))
    return cfg.lr * (1.0 - frac * (1.0 - cfg.final_lr_ratio))


@torch.no_grad()
def evaluate_val(
    model: CVAE,
    fk: PoseFK,
    val: TrainArrays,
    starts: np.ndarray,
    norm: Normalisation,
    cfg: CVAETrainConfig,
) -> float:
    """Validation MPJPE (cm) over windows, decoding with z = 0 (the prior's mean); a
    tracker-set model's windows take the evaluation table's sets in turn."""
    model.eval()
    errs = []
    kinds = cycle_table_kinds(len(starts)) if val.features_imu is not None else None
    for i in range(0, len(starts), 256):
        k = None if kinds is None else kinds[i : i + 256]
        b = _batch(val, starts[i : i + 256], norm, cfg.window, k, device=cfg.device)
        z = torch.zeros(*b["x"].shape[:2], model.cfg.latent, device=b["x"].device)
        if model.cfg.deterministic:
            z, _, _ = model.encoder(b["x"])
        out, _, _ = model.decoder(b["x"], z)
        pred = fk(*_roots(out, b))
        errs.append((pred - b["pos"]).norm(dim=-1).mean(dim=(1, 2)) * 100.0)
    return float(torch.cat(errs).mean()) if errs else float("nan")
