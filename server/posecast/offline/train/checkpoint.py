"""Checkpoints that carry their own config: atomic save, resume, rebuild."""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any

import torch


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
