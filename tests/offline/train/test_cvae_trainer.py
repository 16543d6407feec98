"""``offline/train/cvae_trainer.py``: the learning-rate schedule, the steps a wall-time
budget plans, and short training runs on generated data whose losses go down."""

from __future__ import annotations

import dataclasses
import itertools
from pathlib import Path

import numpy as np
import pytest

from posecast.offline.nets.cvae import CVAEConfig
from posecast.offline.train.checkpoint import load_checkpoint
from posecast.offline.train.cvae_trainer import CVAETrainConfig, learning_rate, train_cvae


def test_constant_then_linear_decay() -> None:
    cfg = CVAETrainConfig(steps=1000, lr=1e-3, decay_from=0.7, final_lr_ratio=0.1)
    assert learning_rate(cfg, 0) == learning_rate(cfg, 699) == 1e-3
    assert learning_rate(cfg, 850) == pytest.approx(1e-3 * (1 - 0.5 * 0.9))
    assert learning_rate(cfg, 1000) == pytest.approx(1e-4)
    rates = [learning_rate(cfg, s) for s in range(700, 1001)]
    assert all(a >= b for a, b in itertools.pairwise(rates))


def test_more_steps_on_resume_moves_the_decay() -> None:
    short, long = CVAETrainConfig(steps=8000), CVAETrainConfig(steps=11000)
    assert learning_rate(short, 7000) < short.lr
    assert learning_rate(long, 7000) == long.lr  # the longer run decays later


def test_a_budget_plans_the_steps_that_fit() -> None:
    from posecast.offline.train.cvae_trainer import plan_steps

    cfg = CVAETrainConfig(steps=20000, budget_s=600.0)
    # 100 steps done after 60 s (data loading included) at 0.1 s a step: 90 % of the
    # 540 s left is 4,860 steps more.
    assert plan_steps(cfg, 100, 60.0, 0.1) == 100 + 4860
    assert plan_steps(cfg, 100, 60.0, 0.001) == 20000  # never more than asked
    assert plan_steps(cfg, 100, 900.0, 0.1) == 101  # over budget: stop at the next step
    # A plan lowered while the machine was slow rises again, up to the steps asked for.
    slow = dataclasses.replace(cfg, steps=2000)
    assert plan_steps(slow, 1000, 60.0, 0.05, most=20000) == 1000 + 9720
    assert plan_steps(slow, 1000, 60.0, 0.05) == 2000


def test_a_budgeted_run_ends_inside_its_budget(prepared_dir, tmp_path) -> None:
    """The run re-plans its steps from its measured speed and stops long before the
    steps asked for, its learning rate decayed (the checkpoint keeps the steps it ran).
    How long it took is not asserted: that depends on the machine's load."""

    from posecast.offline.nets.cvae import CVAEConfig
    from posecast.offline.train.checkpoint import load_checkpoint
    from posecast.offline.train.cvae_trainer import train_cvae

    cfg = CVAETrainConfig(
        steps=10**6, batch=4, window=10, log_every=5, val_every=10**6, ckpt_every=10**6,
        threads=1, speeds=(1.0,), budget_s=8.0,
    )  # fmt: skip
    ckpt = train_cvae(prepared_dir, tmp_path, CVAEConfig(hidden=64), cfg, log=lambda _: None)
    state = load_checkpoint(ckpt)
    steps = state["train_config"]["steps"]
    assert state["step"] == steps < 10**6
    assert any("planned_steps" in h for h in state["history"])
    last = dataclasses.replace(cfg, steps=steps)
    assert learning_rate(last, steps) == pytest.approx(cfg.lr * cfg.final_lr_ratio)


# --- training runs: each loss goes down -------------------------------------------------

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


def test_the_lower_weight_weighs_the_legs_against_the_rest() -> None:
    """Weights normalised to their mean: all 1 is the plain mean; an error on the legs
    alone costs ``w / mean(w)`` times as much, one on the rest ``1 / mean(w)``."""
    import torch

    from posecast.offline.train.cvae_trainer import joint_weights
    from posecast.offline.train.losses import position_mse_cm2
    from posecast.skeleton import LOWER_BODY

    truth = torch.zeros(2, 5, 19, 3, dtype=torch.float64)
    legs = [int(j) for j in LOWER_BODY]
    on_legs, elsewhere = truth.clone(), truth.clone()
    on_legs[..., legs, 0] = 0.01  # 1 cm on each leg joint
    elsewhere[..., [j for j in range(19) if j not in legs], 0] = 0.01
    assert joint_weights(1.0, truth) is None
    w = joint_weights(3.0, truth)
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
