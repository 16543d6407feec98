"""``offline/train/cvae_trainer.py``: the learning-rate schedule and the steps a wall-time
budget plans (that each network's loss goes down is ``test_training.py``'s)."""

from __future__ import annotations

import dataclasses
import itertools

import pytest

from posecast.offline.train.cvae_trainer import CVAETrainConfig, learning_rate


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
