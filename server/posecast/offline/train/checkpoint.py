"""Checkpoints that carry their own config: atomic save, resume, rebuild."""

from __future__ import annotations

import os
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import torch


def start_run(out_dir: str | Path, threads: int) -> Path:
    """Before a training run: torch's CPU threads set to ``threads`` and ``out_dir`` made;
    returns the path of the run's checkpoint there."""
    torch.set_num_threads(threads)
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    return out / "checkpoint.pt"


def save_training(
    path: str | Path,
    kind: str,
    model: torch.nn.Module,
    opt: torch.optim.Optimizer,
    configs: tuple[dict[str, Any], dict[str, Any]],
    norm: dict[str, Any],
    progress: tuple[int, list[dict[str, float]], float],
    data: tuple[str | Path, Mapping[str, Any], int],
    extra: Mapping[str, Any] | None = None,
) -> None:
    """Save a trainer's checkpoint to ``path`` (:func:`save_checkpoint`): its ``kind``,
    the weights (on the CPU), the optimiser's state, ``configs`` (the model's, the
    training's), the feature normalisation ``norm``, ``progress`` (step, history,
    training seconds) and ``data`` (its directory, its manifest, the training frames'
    count), then the trainer's own ``extra`` entries."""
    step, history, elapsed = progress
    data_dir, manifest, train_frames = data
    state = {
        "kind": kind,
        "model": {k: v.cpu() for k, v in model.state_dict().items()},
        "optim": opt.state_dict(),
        "config": configs[0],
        "train_config": configs[1],
        "norm": norm,
        "step": step,
        "history": history,
        "train_seconds": elapsed,
        "data": {"root": str(data_dir), "splits": manifest["splits"]},
        "train_frames": train_frames,
    }
    save_checkpoint(path, state | dict(extra or {}))


def save_checkpoint(path: str | Path, state: dict[str, Any]) -> None:
    """Write ``state`` atomically (a crash mid-write never leaves a torn file)."""
    p = Path(path)
    p.parent.mkdir(parents=True, exist_ok=True)
    tmp = p.with_suffix(p.suffix + ".tmp")
    torch.save(state, tmp)
    os.replace(tmp, p)


def load_checkpoint(path: str | Path) -> dict[str, Any]:
    state: dict[str, Any] = torch.load(Path(path), map_location="cpu", weights_only=False)
    return state


def resume_into(
    path: str | Path, model: torch.nn.Module, opt: torch.optim.Optimizer
) -> tuple[dict[str, Any], int, list[dict[str, float]], float]:
    """Load a training checkpoint's weights into ``model`` and its optimiser state into
    ``opt`` (which moves the moments to the parameters' device). Returns the state for
    the rest, and the progress it records: ``(state, step, history, train seconds)``."""
    state = load_checkpoint(path)
    model.load_state_dict(state["model"])
    opt.load_state_dict(state["optim"])
    return state, state["step"], state["history"], state["train_seconds"]
