"""Checkpoints that carry their own config (offline.train.checkpoint): an atomic save, a
load, a trainer's full state and resuming into a fresh model and optimiser."""

from __future__ import annotations

from pathlib import Path

import pytest
import torch

from posecast.offline.train.checkpoint import (
    load_checkpoint,
    resume_into,
    save_checkpoint,
    save_training,
    start_run,
)


def test_start_run_makes_the_folder_and_names_the_checkpoint(tmp_path: Path) -> None:
    threads = torch.get_num_threads()
    try:
        path = start_run(tmp_path / "runs" / "a", 1)
        assert torch.get_num_threads() == 1
    finally:
        torch.set_num_threads(threads)
    assert path == tmp_path / "runs" / "a" / "checkpoint.pt" and path.parent.is_dir()


def test_a_save_replaces_the_file_whole_and_leaves_no_temporary(tmp_path: Path) -> None:
    path = tmp_path / "deep" / "ck.pt"
    save_checkpoint(path, {"step": 1, "w": torch.arange(3.0)})
    save_checkpoint(path, {"step": 2, "w": torch.arange(4.0)})
    state = load_checkpoint(path)
    assert state["step"] == 2 and torch.equal(state["w"], torch.arange(4.0))
    assert sorted(p.name for p in path.parent.iterdir()) == ["ck.pt"]


def test_a_training_checkpoint_resumes_model_optimiser_and_progress(tmp_path: Path) -> None:
    torch.manual_seed(0)
    model = torch.nn.Linear(3, 2)
    opt = torch.optim.Adam(model.parameters(), lr=1e-2)
    model(torch.randn(4, 3)).pow(2).sum().backward()
    opt.step()  # the optimiser now has moments to carry
    history = [{"step": 1.0, "loss": 0.5}]
    path = tmp_path / "checkpoint.pt"
    save_training(
        path, "ae", model, opt, ({"latent": 0}, {"steps": 10}), {"feat_mean": [0.0]},
        (1, history, 2.5), (tmp_path / "data", {"splits": {"train": 3}}, 120),
        extra={"val_error_p99_m": 0.04},
    )  # fmt: skip
    state = load_checkpoint(path)
    assert state["kind"] == "ae" and state["config"] == {"latent": 0}
    assert state["train_config"] == {"steps": 10} and state["norm"] == {"feat_mean": [0.0]}
    assert state["data"] == {"root": str(tmp_path / "data"), "splits": {"train": 3}}
    assert state["train_frames"] == 120 and state["val_error_p99_m"] == 0.04

    fresh = torch.nn.Linear(3, 2)
    fresh_opt = torch.optim.Adam(fresh.parameters(), lr=1e-2)
    _, step, hist, seconds = resume_into(path, fresh, fresh_opt)
    assert (step, hist, seconds) == (1, history, pytest.approx(2.5))
    for a, b in zip(model.parameters(), fresh.parameters(), strict=True):
        assert torch.equal(a, b)
    moments = [s["exp_avg"] for s in fresh_opt.state.values()]
    assert len(moments) == 2 and all(m.abs().sum() > 0 for m in moments)
