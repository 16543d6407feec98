"""Torch twins of the numpy rotation and FK code, for training losses.

Only what the networks need: 6D to matrix and FK. The numpy versions in
:mod:`posecast.geometry.rotations` and :mod:`posecast.geometry.fk` are the
reference; ``tests/geometry/test_torch_ops.py`` checks parity to 1e-5.
"""

from __future__ import annotations

from collections.abc import Sequence

import torch

from posecast.skeleton import PARENTS


def r6d2mat(d: torch.Tensor) -> torch.Tensor:
    """``(..., 6)`` -> ``(..., 3, 3)`` by Gram-Schmidt (columns ``b1 b2 b3``)."""
    a1, a2 = d[..., 0:3], d[..., 3:6]
    b1 = torch.nn.functional.normalize(a1, dim=-1, eps=1e-12)
    b2 = a2 - (b1 * a2).sum(dim=-1, keepdim=True) * b1
    b2 = torch.nn.functional.normalize(b2, dim=-1, eps=1e-12)
    b3 = torch.cross(b1, b2, dim=-1)
    return torch.stack([b1, b2, b3], dim=-1)


def mat2r6d(m: torch.Tensor) -> torch.Tensor:
    """``(..., 3, 3)`` -> ``(..., 6)``: the first two columns."""
    return torch.cat([m[..., :, 0], m[..., :, 1]], dim=-1)


def fk(
    local_mat: torch.Tensor,
    root_pos: torch.Tensor,
    offsets: torch.Tensor,
    parents: Sequence[int] = PARENTS,
) -> tuple[torch.Tensor, torch.Tensor]:
    """World rotations ``(..., J, 3, 3)`` and positions ``(..., J, 3)``.

    Same contract as :func:`posecast.geometry.fk.fk_mat`; written without
    in-place writes so autograd works.
    """
    n = len(parents)
    off = offsets.expand(*local_mat.shape[:-3], n, 3)
    gmat: list[torch.Tensor] = []
    gpos: list[torch.Tensor] = []
    for j, p in enumerate(parents):
        if p < 0:
            gmat.append(local_mat[..., j, :, :])
            gpos.append(root_pos + off[..., j, :])
        else:
            gmat.append(gmat[p] @ local_mat[..., j, :, :])
            gpos.append(gpos[p] + (gmat[p] @ off[..., j, :, None])[..., 0])
    return torch.stack(gmat, dim=-3), torch.stack(gpos, dim=-2)
