"""Float32 FK for the engine's hot path (thousands of samples per tick).

Same math as :mod:`posecast.geometry.fk`, specialised: float32 throughout,
the reference offsets fixed, and the arrays laid out component-major (``(3, 3, B)``
per joint). numpy multiplies a batch of 3x3 matrices about 5x faster as nine
contiguous vector operations than through ``matmul`` on ``(B, 3, 3)`` stacks.
``tests/body/test_batch_fk.py`` checks it against the float64 reference.
"""

from __future__ import annotations

import functools

import numpy as np
from numpy.typing import NDArray

from posecast.geometry.rotations import quat2yaw
from posecast.skeleton import NUM_ROTATIONS, PARENTS, reference_offsets

F32 = NDArray[np.float32]
_OFFSETS = reference_offsets().astype(np.float32)


def r6d2mat32(d: F32) -> F32:
    """``(..., 6)`` -> ``(..., 3, 3)``, Gram-Schmidt in float32."""
    out: F32 = np.empty((*d.shape[:-1], 3, 3), np.float32)
    for k, column in enumerate(_columns32(d)):
        out[..., :, k] = column
    return out


def _columns32(d: F32) -> tuple[F32, F32, F32]:
    """The three columns ``(..., 3)`` of :func:`r6d2mat32`'s matrices: the dot products
    and the cross product written out, which numpy runs about twice as fast as
    ``linalg.norm``, ``cross`` and ``stack`` on a few thousand rows (the same
    arithmetic, so the same bits)."""
    a1, a2 = d[..., 0:3], d[..., 3:6]
    b1 = a1 / np.maximum(np.sqrt(np.einsum("...i,...i->...", a1, a1))[..., None], 1e-8)
    b2 = a2 - np.einsum("...i,...i->...", b1, a2)[..., None] * b1
    b2 /= np.maximum(np.sqrt(np.einsum("...i,...i->...", b2, b2))[..., None], 1e-8)
    b3 = np.empty_like(b1)
    b3[..., 0] = b1[..., 1] * b2[..., 2] - b1[..., 2] * b2[..., 1]
    b3[..., 1] = b1[..., 2] * b2[..., 0] - b1[..., 0] * b2[..., 2]
    b3[..., 2] = b1[..., 0] * b2[..., 1] - b1[..., 1] * b2[..., 0]
    return b1, b2, b3


def _local_soa(rot6d: F32, B: int, rows: list[int]) -> F32:
    """Network 6D rotations ``(B, 108)`` -> local matrices ``(len(rows), 3, 3, B)`` of the
    given rotation rows (joint ``j`` is row ``j - 1``)."""
    d = np.ascontiguousarray(rot6d.reshape(B, NUM_ROTATIONS, 6)[:, rows].transpose(1, 2, 0))
    a1, a2 = d[:, 0:3], d[:, 3:6]  # (R, 3, B)
    b1 = a1 / np.maximum(np.sqrt((a1 * a1).sum(axis=1, keepdims=True)), 1e-8)
    b2 = a2 - (b1 * a2).sum(axis=1, keepdims=True) * b1
    b2 /= np.maximum(np.sqrt((b2 * b2).sum(axis=1, keepdims=True)), 1e-8)
    b3 = np.empty_like(b1)  # b1 x b2, written out (np.cross is slow on small stacks)
    b3[:, 0] = b1[:, 1] * b2[:, 2] - b1[:, 2] * b2[:, 1]
    b3[:, 1] = b1[:, 2] * b2[:, 0] - b1[:, 0] * b2[:, 2]
    b3[:, 2] = b1[:, 0] * b2[:, 1] - b1[:, 1] * b2[:, 0]
    out: F32 = np.stack([b1, b2, b3], axis=2)  # columns: [r, row, col, b]
    return out


@functools.cache
def _plan(want_mats: bool, joints: tuple[int, ...] | None) -> tuple[list[int], list[int]]:
    """Joints whose positions to compute, and joints whose world rotation is needed."""
    wanted = set(range(len(PARENTS)) if joints is None else joints)
    for j in list(wanted):
        while PARENTS[j] >= 0:
            j = PARENTS[j]
            wanted.add(j)
    parents = {PARENTS[j] for j in wanted if PARENTS[j] >= 0}
    mats = wanted if want_mats else parents | {0}
    return sorted(wanted), sorted(mats)


def fk32(
    rot6d: F32,
    root_mat: F32,
    root_pos: F32,
    want_mats: bool = True,
    joints: tuple[int, ...] | None = None,
) -> tuple[F32 | None, F32]:
    """World rotations ``(B, 19, 3, 3)`` (or ``None``) and positions ``(B, 19, 3)``.

    Args:
        rot6d: ``(B, 108)`` or ``(B, 18, 6)`` network rotations.
        root_mat: ``(B, 3, 3)`` pelvis world rotation; root_pos: ``(B, 3)``.
        want_mats: also return world rotations. Without them, leaf joints (head,
            hands, toes) cost no matrix product at all.
        joints: compute only these joints' positions (and their ancestors'); the other
            rows of the result are left undefined. ``None``: all 19.
    """
    B = root_pos.shape[0]
    pos_joints, mat_joints = _plan(want_mats, joints)
    rows = {j: r for r, j in enumerate(j for j in mat_joints if j > 0)}
    local = _local_soa(rot6d, B, [j - 1 for j in rows])
    wm = np.empty((len(PARENTS), 3, 3, B), np.float32)
    wp = np.empty((len(PARENTS), 3, B), np.float32)
    wm[0] = root_mat.transpose(1, 2, 0)
    wp[0] = root_pos.T
    for j in pos_joints[1:]:
        p = PARENTS[j]
        np.add(wp[p], np.sum(wm[p] * _OFFSETS[j][None, :, None], axis=1), out=wp[j])
        if j in rows:  # W_j[i, k] = sum_m W_p[i, m] L_j[m, k]
            np.sum(wm[p][:, :, None, :] * local[rows[j]][None, :, :, :], axis=1, out=wm[j])
    pos: F32 = np.ascontiguousarray(wp.transpose(2, 0, 1))
    if not want_mats:
        return None, pos
    mats: F32 = np.ascontiguousarray(wm.transpose(3, 0, 1, 2))
    return mats, pos


def pelvis_from_head32(
    root_out: F32, head_pos: NDArray[np.floating], head_quat: NDArray[np.floating]
) -> tuple[F32, F32]:
    """:func:`posecast.tracking.layouts.pelvis_from_head` for ``G`` heads ``(G, 3)`` /
    ``(G, 4)`` whose rows of ``root_out (G * n, 9)`` come in consecutive groups of
    ``n`` (a player's samples): the head's heading is taken once per head, and its
    rotation about +Y is applied to the rows' 6D pelvis and position component-wise in
    float32 (within 1e-5 of the float64 reference,
    ``tests/body/test_batch_fk.py``)."""
    G = len(head_pos)
    n = len(root_out) // max(G, 1)
    h = quat2yaw(head_quat)  # heading of each head: the frame is a turn about +Y by it
    c = np.cos(h).astype(np.float32)[:, None]
    s = np.sin(h).astype(np.float32)[:, None]
    out = np.asarray(root_out, dtype=np.float32).reshape(G, n, -1)
    mats = np.empty((G, n, 3, 3), np.float32)
    # Y(h) @ m column by column: each column's x and z turn, its y stays.
    for k, b in enumerate(_columns32(out[..., :6])):
        mats[..., 0, k] = c * b[..., 0] + s * b[..., 2]
        mats[..., 1, k] = b[..., 1]
        mats[..., 2, k] = c * b[..., 2] - s * b[..., 0]
    p = out[..., 6:9]
    places = np.empty((G, n, 3), np.float32)
    hp = np.asarray(head_pos, dtype=np.float32)
    places[..., 0] = hp[:, None, 0] + c * p[..., 0] + s * p[..., 2]
    places[..., 1] = p[..., 1]
    places[..., 2] = hp[:, None, 2] + c * p[..., 2] - s * p[..., 0]
    return mats.reshape(G * n, 3, 3), places.reshape(G * n, 3)
