from __future__ import annotations

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
