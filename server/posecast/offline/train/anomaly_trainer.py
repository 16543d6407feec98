"""``posecast train anomaly``: the pose-plausibility autoencoder (paper Sec. 3.2.1, 4.3).

Trained on single frames of natural motion (the augmented training split). After
training, the reconstruction error of every validation frame is measured; its 99th
percentile becomes the ``implausible`` threshold that evaluation reports against.
"""

from __future__ import annotations

import json
import time
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import numpy as np
import torch

from posecast.offline.dataset.augment import Augmentation
from posecast.offline.nets.anomaly import AnomalyAE, AnomalyConfig
from posecast.offline.train.checkpoint import resume_into, save_training, start_run
from posecast.offline.train.data import Normalisation, TrainArrays, load_train_val
from posecast.offline.train.losses import PoseFK, position_mse_cm2
from posecast.skeleton import LOWER_BODY


@dataclass(frozen=True)
class AnomalyTrainConfig:
    steps: int = 20000
    batch: int = 512
    lr: float = 2e-4  # paper Sec. 4.3: lr 2e-4, beta1 0.5
    beta1: float = 0.5
    seed: int = 0
    log_every: int = 500
    ckpt_every: int = 2000
    threads: int = 2
    mirror: bool = True
    speeds: tuple[float, ...] = (1.0,)


def _tensors(arr: TrainArrays, idx: np.ndarray, norm: Normalisation) -> dict[str, torch.Tensor]:
    pos = arr.local_pos[idx]  # (B, 19, 3)
    x = (pos.reshape(len(idx), 57) - norm.pose_mean) / norm.pose_std
    return {
        "x": torch.from_numpy(np.ascontiguousarray(x, dtype=np.float32)),
        "pos": torch.from_numpy(pos),
        "root_mat": torch.from_numpy(arr.root_mat[idx]),
    }


@torch.no_grad()
def lower_body_errors_m(
    model: AnomalyAE, fk: PoseFK, arr: TrainArrays, norm: Normalisation
) -> np.ndarray:
    """Per-frame mean lower-body reconstruction error ``R`` in metres."""
    model.eval()
    out = []
    lower = [int(j) for j in LOWER_BODY]
    for i in range(0, arr.n_frames, 4096):
        b = _tensors(arr, np.arange(i, min(i + 4096, arr.n_frames)), norm)
        rec = fk(model(b["x"]), b["root_mat"], b["pos"][:, 0])
        out.append((rec - b["pos"])[:, lower].norm(dim=-1).mean(dim=-1).numpy())
    return np.concatenate(out) if out else np.zeros(0)


def train_anomaly(
    data_dir: str | Path,
    out_dir: str | Path,
    cfg: AnomalyTrainConfig,
    resume: bool = False,
    log: Any = print,
) -> Path:
    ckpt_path = start_run(out_dir, cfg.threads)
    aug = Augmentation(mirror=cfg.mirror, speeds=cfg.speeds)
    manifest, train, val = load_train_val(data_dir, aug, cfg.seed)
    log(f"data: {train.n_frames} train frames, {val.n_frames} val frames")
    torch.manual_seed(cfg.seed)
    model_cfg = AnomalyConfig()
    model, fk = AnomalyAE(model_cfg), PoseFK()
    opt = torch.optim.Adam(model.parameters(), lr=cfg.lr, betas=(cfg.beta1, 0.999))
    norm = Normalisation.fit(train)
    step, elapsed = 0, 0.0
    history: list[dict[str, float]] = []
    if resume and ckpt_path.exists():
        state, step, history, elapsed = resume_into(ckpt_path, model, opt)
        norm = Normalisation.from_dict(state["norm"])
        log(f"resumed from {ckpt_path} at step {step}")
    rng = np.random.default_rng(cfg.seed + step)

    def save(extra: dict[str, object] | None = None) -> None:
        save_training(
            ckpt_path,
            "anomaly",
            model,
            opt,
            (model_cfg.to_dict(), asdict(cfg)),
            norm.to_dict(),
            (step, history, elapsed),
            (data_dir, manifest, train.n_frames),
            extra,
        )

    t_log = time.perf_counter()
    model.train()
    while step < cfg.steps:
        b = _tensors(train, rng.integers(0, train.n_frames, cfg.batch), norm)
        loss = position_mse_cm2(fk(model(b["x"]), b["root_mat"], b["pos"][:, 0]), b["pos"])
        opt.zero_grad(set_to_none=True)
        loss.backward()  # type: ignore[no-untyped-call]
        opt.step()
        step += 1
        if step % cfg.log_every == 0 or step == cfg.steps:
            dt = time.perf_counter() - t_log
            elapsed += dt
            rec = {"step": step, "mse_cm2": float(loss.detach()), "seconds": elapsed}
            rec["frames_per_s"] = cfg.log_every * cfg.batch / dt
            history.append(rec)
            log(json.dumps({k: round(v, 4) if isinstance(v, float) else v for k, v in rec.items()}))
            t_log = time.perf_counter()
            model.train()
        if step % cfg.ckpt_every == 0:
            save()
    errs = lower_body_errors_m(model, fk, val, norm)
    p99 = float(np.percentile(errs, 99)) if errs.size else float("nan")
    log(f"val lower-body error: mean {errs.mean() * 100:.2f} cm, p99 {p99 * 100:.2f} cm")
    save({"val_error_p99_m": p99, "val_error_mean_m": float(errs.mean())})
    return ckpt_path
