"""Each network trains for a few dozen steps on generated data and its loss goes down."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from posecast.offline.nets.cvae import CVAEConfig
from posecast.offline.train.anomaly_trainer import AnomalyTrainConfig, train_anomaly
from posecast.offline.train.checkpoint import load_checkpoint
from posecast.offline.train.cvae_trainer import CVAETrainConfig, train_cvae

SMALL = CVAETrainConfig(
    steps=40, batch=8, window=20, log_every=1, val_every=40, ckpt_every=20, threads=1,
    speeds=(1.0,), bone_scale=(0.95, 1.05), bone_jitter=0.02,
)  # fmt: skip


def _losses(ckpt: Path, key: str = "loss") -> np.ndarray:
    return np.array([h[key] for h in load_checkpoint(ckpt)["history"]])


def test_cvae_loss_decreases(prepared_dir: Path, tmp_path: Path) -> None:
    ckpt = train_cvae(prepared_dir, tmp_path, CVAEConfig(), SMALL, log=lambda _: None)
    loss = _losses(ckpt)
    assert len(loss) == 40
    assert loss[-5:].mean() < 0.5 * loss[:5].mean()
    state = load_checkpoint(ckpt)
    assert state["kind"] == "cvae" and state["config"]["latent"] == 30
    assert np.isfinite(state["history"][-1]["val_mpjpe_cm"])


def test_ae_loss_decreases(prepared_dir: Path, tmp_path: Path) -> None:
    cfg = CVAEConfig(deterministic=True, encoder_sees_pose=False)
    ckpt = train_cvae(prepared_dir, tmp_path, cfg, SMALL, log=lambda _: None)
    loss = _losses(ckpt)
    assert loss[-5:].mean() < 0.5 * loss[:5].mean()
    assert load_checkpoint(ckpt)["kind"] == "ae"


def test_anomaly_loss_decreases(prepared_dir: Path, tmp_path: Path) -> None:
    cfg = AnomalyTrainConfig(steps=60, batch=64, log_every=5, ckpt_every=30, threads=1)
    ckpt = train_anomaly(prepared_dir, tmp_path, cfg, log=lambda _: None)
    loss = _losses(ckpt, "mse_cm2")
    assert loss[-3:].mean() < 0.7 * loss[:3].mean()
    assert load_checkpoint(ckpt)["val_error_p99_m"] > 0


def test_resume_continues_where_it_stopped(prepared_dir: Path, tmp_path: Path) -> None:
    import dataclasses

    first = dataclasses.replace(SMALL, steps=20)
    train_cvae(prepared_dir, tmp_path, CVAEConfig(), first, log=lambda _: None)
    logs: list[str] = []
    ckpt = train_cvae(prepared_dir, tmp_path, CVAEConfig(), SMALL, resume=True, log=logs.append)
    assert any("resumed" in line and "step 20" in line for line in logs)
    steps = [h["step"] for h in load_checkpoint(ckpt)["history"]]
    assert steps == list(range(1, 41))


def test_hmd3_cvae_learns_the_pelvis_and_rotations(prepared_dir: Path, tmp_path: Path) -> None:
    """The headset-only CVAE: 36 inputs, 117 pose outputs (the pelvis included), the
    rotation term logged and falling with the position loss."""
    import dataclasses

    cfg = CVAEConfig(n_features=36, layout="hmd3", root_outputs=9)
    train_cfg = dataclasses.replace(SMALL, rot_weight=10.0)
    ckpt = train_cvae(prepared_dir, tmp_path, cfg, train_cfg, log=lambda _: None)
    loss, rot = _losses(ckpt), _losses(ckpt, "rot_frob2")
    assert loss[-5:].mean() < 0.5 * loss[:5].mean()
    assert rot[-5:].mean() < rot[:5].mean()
    state = load_checkpoint(ckpt)
    assert state["model"]["decoder.pose.weight"].shape == (117, 128)
    assert state["model"]["decoder.fc.weight"].shape == (128, 36 + 30)
    assert state["config"]["layout"] == "hmd3"


def test_the_orientation_ablation_zeroes_only_orientation_inputs(
    prepared_dir: Path, tmp_path: Path
) -> None:
    import dataclasses

    cfg = CVAEConfig(n_features=36, layout="hmd3", root_outputs=9)
    train_cfg = dataclasses.replace(SMALL, steps=4, log_every=2, val_every=4, no_orientation=True)
    ckpt = train_cvae(prepared_dir, tmp_path, cfg, train_cfg, log=lambda _: None)
    std = np.asarray(load_checkpoint(ckpt)["norm"]["feat_std"])
    from posecast.tracking.features import FEATURE_NAMES_HMD3

    ori = np.array([".r" in n for n in FEATURE_NAMES_HMD3])
    assert np.all(std[ori] == np.float32(1e-3))  # constant zero: the std floor
    assert np.all(std[~ori] > 1e-3)
    with pytest.raises(ValueError, match="no orientation"):
        train_cvae(prepared_dir, tmp_path / "four", CVAEConfig(), train_cfg, log=lambda _: None)


def test_the_velocity_term_scores_frame_to_frame_motion_only() -> None:
    import torch

    from posecast.offline.train.losses import velocity_mse_cm2

    g = torch.Generator().manual_seed(0)
    truth = torch.randn(2, 10, 19, 3, generator=g, dtype=torch.float64) * 0.1
    offset = truth + torch.tensor([0.05, -0.02, 0.01], dtype=torch.float64)  # 5 cm off, steady
    assert float(velocity_mse_cm2(offset, truth)) == pytest.approx(0.0, abs=1e-9)
    jitter = truth.clone()
    jitter[:, 1::2, :, 1] += 0.01  # every other frame 1 cm up: each displacement is 1 cm off in y
    assert float(velocity_mse_cm2(jitter, truth)) == pytest.approx(1.0 / 3.0)


def test_the_lower_weight_weighs_the_legs_against_the_rest() -> None:
    """Weights normalised to their mean: all 1 is the plain mean; an error on the legs
    alone costs ``w / mean(w)`` times as much, one on the rest ``1 / mean(w)``."""
    import torch

    from posecast.offline.train.cvae_trainer import _joint_weights
    from posecast.offline.train.losses import position_mse_cm2
    from posecast.skeleton import LOWER_BODY

    truth = torch.zeros(2, 5, 19, 3, dtype=torch.float64)
    legs = [int(j) for j in LOWER_BODY]
    on_legs, elsewhere = truth.clone(), truth.clone()
    on_legs[..., legs, 0] = 0.01  # 1 cm on each leg joint
    elsewhere[..., [j for j in range(19) if j not in legs], 0] = 0.01
    assert _joint_weights(1.0, truth) is None
    w = _joint_weights(3.0, truth)
    assert w is not None and float(w.mean()) == pytest.approx((3 * 8 + 11) / 19)
    plain_legs = float(position_mse_cm2(on_legs, truth))
    assert plain_legs == pytest.approx(8 / (19 * 3))  # 1 cm^2 on one of 3 axes
    assert float(position_mse_cm2(on_legs, truth, w)) == pytest.approx(plain_legs * 3 / w.mean())
    plain_rest = float(position_mse_cm2(elsewhere, truth))
    assert float(position_mse_cm2(elsewhere, truth, w)) == pytest.approx(plain_rest / w.mean())
    assert len(legs) == 8


def test_the_velocity_term_is_logged_and_falls(prepared_dir: Path, tmp_path: Path) -> None:
    import dataclasses

    cfg = dataclasses.replace(SMALL, vel_weight=30.0)
    ckpt = train_cvae(prepared_dir, tmp_path, CVAEConfig(), cfg, log=lambda _: None)
    vel = _losses(ckpt, "vel_mse_cm2")
    assert len(vel) == 40 and vel[-5:].mean() < vel[:5].mean()
    assert load_checkpoint(ckpt)["train_config"]["vel_weight"] == 30.0
