"""Forward kinematics in numpy, batched over any leading shape.

The same math lives in :mod:`posecast.geometry.torch_ops` for training; a
parity test keeps the two equal to 1e-5.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from numpy.typing import ArrayLike, NDArray

from posecast.skeleton import PARENTS

F = NDArray[np.float64]


def fk_mat(
    local_mat: ArrayLike,
    root_pos: ArrayLike,
    offsets: ArrayLike,
    parents: Sequence[int] = PARENTS,
) -> tuple[F, F]:
    """World rotations and positions from local rotation matrices.

    Args:
        local_mat: ``(..., J, 3, 3)`` local rotations; joint 0 is the root and its
            rotation is the root's world rotation.
        root_pos: ``(..., 3)`` root world position, metres.
        offsets: ``(J, 3)`` or ``(..., J, 3)`` rest offsets from each parent, metres.
        parents: parent index per joint, ``-1`` for the root, parents first.

    Returns:
        ``(world_mat (..., J, 3, 3), world_pos (..., J, 3))``.
    """
    L = np.asarray(local_mat, dtype=np.float64)
    root = np.asarray(root_pos, dtype=np.float64)
    off = np.asarray(offsets, dtype=np.float64)
    n = len(parents)
    if L.shape[-3] != n:
        raise ValueError(f"expected {n} joints, got local rotations of shape {L.shape}")
    off = np.broadcast_to(off, (*L.shape[:-3], n, 3))
    gmat = np.empty_like(L)
    gpos = np.empty((*L.shape[:-3], n, 3))
    for j, p in enumerate(parents):
        if p < 0:
            gmat[..., j, :, :] = L[..., j, :, :]
            gpos[..., j, :] = root + off[..., j, :]
        else:
            gmat[..., j, :, :] = gmat[..., p, :, :] @ L[..., j, :, :]
            gpos[..., j, :] = gpos[..., p, :] + np.einsum(
                "...ab,...b->...a", gmat[..., p, :, :], off[..., j, :]
            )
    return gmat, gpos


def fk_positions(
    local_mat: ArrayLike,
    root_pos: ArrayLike,
    offsets: ArrayLike,
    parents: Sequence[int] = PARENTS,
) -> F:
    """World joint positions ``(..., J, 3)``; see :func:`fk_mat`."""
    return fk_mat(local_mat, root_pos, offsets, parents)[1]


def world2local_mat(world_mat: ArrayLike, parents: Sequence[int] = PARENTS) -> F:
    """Local rotations from world rotations: ``L_j = W_parent^T @ W_j``."""
    W = np.asarray(world_mat, dtype=np.float64)
    L = np.empty_like(W)
    for j, p in enumerate(parents):
        if p < 0:
            L[..., j, :, :] = W[..., j, :, :]
        else:
            L[..., j, :, :] = np.swapaxes(W[..., p, :, :], -1, -2) @ W[..., j, :, :]
    return L
