"""The anomaly autoencoder's trainer (offline.train.anomaly_trainer) on generated data."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from posecast.offline.train.anomaly_trainer import AnomalyTrainConfig, train_anomaly
from posecast.offline.train.checkpoint import load_checkpoint


def _losses(ckpt: Path, key: str = "loss") -> np.ndarray:
    return np.array([h[key] for h in load_checkpoint(ckpt)["history"]])


def test_anomaly_loss_decreases(prepared_dir: Path, tmp_path: Path) -> None:
    cfg = AnomalyTrainConfig(steps=60, batch=64, log_every=5, ckpt_every=30, threads=1)
    ckpt = train_anomaly(prepared_dir, tmp_path, cfg, log=lambda _: None)
    loss = _losses(ckpt, "mse_cm2")
    assert loss[-3:].mean() < 0.7 * loss[:3].mean()
    assert load_checkpoint(ckpt)["val_error_p99_m"] > 0
