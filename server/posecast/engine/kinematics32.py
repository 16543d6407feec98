"""Float32 FK for the engine's hot path (thousands of samples per tick).

Same math as :mod:`posecast.geometry.kinematics`, specialised: float32 throughout,
the reference offsets fixed, and positions computed with one batched matmul per
joint. ``tests/engine/test_kinematics32.py`` checks it against the float64 reference.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from posecast.skeleton import NUM_ROTATIONS, PARENTS, reference_offsets

F32 = NDArray[np.float32]
_OFFSETS = reference_offsets().astype(np.float32)


def r6d2mat32(d: F32) -> F32:
    """``(..., 6)`` -> ``(..., 3, 3)``, Gram-Schmidt in float32."""
    a1, a2 = d[..., 0:3], d[..., 3:6]
    b1 = a1 / np.maximum(np.linalg.norm(a1, axis=-1, keepdims=True), 1e-8)
    b2 = a2 - np.sum(b1 * a2, axis=-1, keepdims=True) * b1
    b2 /= np.maximum(np.linalg.norm(b2, axis=-1, keepdims=True), 1e-8)
    b3 = np.cross(b1, b2)
    out: F32 = np.stack([b1, b2, b3], axis=-1)
    return out


def fk32(rot6d: F32, root_mat: F32, root_pos: F32) -> tuple[F32, F32]:
    """World rotations ``(B, 19, 3, 3)`` and positions ``(B, 19, 3)`` on the reference body.

    Args:
        rot6d: ``(B, 108)`` or ``(B, 18, 6)`` network rotations.
        root_mat: ``(B, 3, 3)`` pelvis world rotation; root_pos: ``(B, 3)``.
    """
    B = root_pos.shape[0]
    local = r6d2mat32(rot6d.reshape(B, NUM_ROTATIONS, 6))  # (B, 18, 3, 3)
    wm = np.empty((B, len(PARENTS), 3, 3), np.float32)
    wp = np.empty((B, len(PARENTS), 3), np.float32)
    wm[:, 0] = root_mat
    wp[:, 0] = root_pos
    for j in range(1, len(PARENTS)):
        p = PARENTS[j]
        np.matmul(wm[:, p], local[:, j - 1], out=wm[:, j])
        wp[:, j] = wp[:, p] + wm[:, p] @ _OFFSETS[j]
    return wm, wp
