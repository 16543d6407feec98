"""Losses in position space: rotations are scored by where they put the joints."""

from __future__ import annotations

import torch

from posecast.geometry.torch_ops import fk, r6d2mat
from posecast.skeleton import reference_offsets


class PoseFK(torch.nn.Module):
    """Character-frame joint positions from predicted rotations, on the reference body."""

    def __init__(self) -> None:
        super().__init__()
        self.register_buffer("offsets", torch.tensor(reference_offsets(), dtype=torch.float32))

    def forward(
        self, rot6d: torch.Tensor, root_mat: torch.Tensor, root_pos: torch.Tensor
    ) -> torch.Tensor:
        """``rot6d (..., 108)``, ``root_mat (..., 3, 3)``, ``root_pos (..., 3)``
        -> positions ``(..., 19, 3)``."""
        local = r6d2mat(rot6d.reshape(*rot6d.shape[:-1], 18, 6))  # (..., 18, 3, 3)
        local = torch.cat([root_mat.unsqueeze(-3), local], dim=-3)  # (..., 19, 3, 3)
        offsets: torch.Tensor = self.offsets  # type: ignore[assignment]
        return fk(local, root_pos, offsets)[1]


def split_root(
    out: torch.Tensor, root_mat: torch.Tensor, root_pos: torch.Tensor
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """The decoder's pose output and the pelvis pose FK should use.

    ``out (..., 108)``: the pelvis comes from the data (``root_mat``, ``root_pos``, the
    waist tracker's at serving time). ``out (..., 117)``: the model predicts it, 6D
    rotation then position, in the same frame as the targets.
    """
    if out.shape[-1] == 108:
        return out, root_mat, root_pos
    return out[..., :108], r6d2mat(out[..., 108:114]), out[..., 114:117]


def position_mse_cm2(
    pred: torch.Tensor, target: torch.Tensor, joint_weights: torch.Tensor | None = None
) -> torch.Tensor:
    """Mean squared joint position error in cm^2 (positions ``(..., J, 3)`` in metres);
    with ``joint_weights (J,)`` each joint's squared error weighted, normalised to the
    weights' mean (all 1: the plain mean)."""
    sq = ((pred - target) * 100.0).pow(2)
    if joint_weights is None:
        return sq.mean()
    return (sq * joint_weights[:, None]).mean() / joint_weights.mean()


def velocity_mse_cm2(pred: torch.Tensor, target: torch.Tensor) -> torch.Tensor:
    """Mean squared error of the joints' frame-to-frame displacement, cm^2 (positions
    ``(B, T, J, 3)`` in metres; the difference is taken along ``T``)."""
    dp, dt = pred[:, 1:] - pred[:, :-1], target[:, 1:] - target[:, :-1]
    return ((dp - dt) * 100.0).pow(2).mean()
