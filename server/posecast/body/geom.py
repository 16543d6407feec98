"""Small-array geometry the shown pose's passes share (numpy, batched).

The vector helpers are written out by component: numpy's ``cross`` and ``linalg.norm``
cost more in call overhead than in arithmetic at a tick's few rows. The body's bones:
:data:`BONE_M`, and :func:`turn_joint`, the one way a pass turns a joint (with its whole
subtree, so world rotations stay what FK of the local ones gives).
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from posecast.skeleton import NUM_JOINTS, PARENTS, reference_offsets

D64 = NDArray[np.float64]

EPS = 1e-9  # below this a length counts as zero
BONE_M = np.linalg.norm(reference_offsets(), axis=-1)  # (19,) length of each joint's bone


def norm3(v: D64) -> D64:
    """Lengths ``(...,)`` of vectors ``(..., 3)``."""
    out: D64 = np.sqrt(np.einsum("...i,...i->...", v, v))
    return out


def cross3(a: D64, b: D64) -> D64:
    """Cross products of ``(..., 3)`` vectors."""
    a0, a1, a2 = a[..., 0], a[..., 1], a[..., 2]
    b0, b1, b2 = b[..., 0], b[..., 1], b[..., 2]
    return np.stack([a1 * b2 - a2 * b1, a2 * b0 - a0 * b2, a0 * b1 - a1 * b0], axis=-1)


def unit3(v: D64) -> tuple[D64, D64]:
    """``v (..., 3)`` -> (direction, length ``(...,)``); a zero vector keeps direction 0."""
    n = norm3(v)
    return v / np.maximum(n, EPS)[..., None], n


def swing_mat(a: D64, b: D64) -> D64:
    """The smallest rotation ``(..., 3, 3)`` taking direction ``a (..., 3)`` onto ``b``
    (Rodrigues' formula, ``R = c I + [v]x + v v^T / (1 + c)`` with ``v = a x b``,
    ``c = a . b``; opposite directions turn half a turn about a perpendicular)."""
    ua, _ = unit3(a)
    ub, _ = unit3(b)
    x, y, z = np.moveaxis(cross3(ua, ub), -1, 0)  # the axis times sin
    c = np.einsum("...i,...i->...", ua, ub)  # cos
    opposite = c < -1.0 + 1e-9
    h = 1.0 / np.where(opposite, 1.0, 1.0 + c)
    xh, yh, zh = x * h, y * h, z * h
    R = np.stack(
        [
            c + x * xh, y * xh - z, z * xh + y,
            y * xh + z, c + y * yh, z * yh - x,
            z * xh - y, z * yh + x, c + z * zh,
        ],
        axis=-1,
    ).reshape(*c.shape, 3, 3)  # fmt: skip
    if opposite.any():
        helper = np.where(np.abs(ua[..., :1]) < 0.9, [1.0, 0.0, 0.0], [0.0, 1.0, 0.0])
        p, _ = unit3(cross3(ua, helper))
        half = 2.0 * p[..., :, None] * p[..., None, :] - np.eye(3)
        R = np.where(opposite[..., None, None], half, R)
    return R


def wrap_angle(angle: D64) -> D64:
    """``angle`` (radians) into ``[-pi, pi)``."""
    out: D64 = (angle + np.pi) % (2.0 * np.pi) - np.pi
    return out


def _descendants() -> dict[int, list[int]]:
    out: dict[int, list[int]] = {j: [] for j in range(NUM_JOINTS)}
    for j in range(NUM_JOINTS):
        p = PARENTS[j]
        while p >= 0:
            out[p].append(j)
            p = PARENTS[p]
    return out


DESCENDANTS = _descendants()  # per joint, every joint below it


def turn_joint(pos: D64, mat: D64, joint: int, R: D64) -> None:
    """Turn ``joint``'s world rotation by ``R (E, 3, 3)`` (on the left) about its own
    position, with its whole subtree, in place: what FK gives after that change
    (positions ``(E, 19, 3)``, world rotations ``(E, 19, 3, 3)``)."""
    sub = DESCENDANTS[joint]
    pivot = pos[:, joint, None]  # (E, 1, 3)
    pos[:, sub] = pivot + np.einsum("eab,ekb->eka", R, pos[:, sub] - pivot)
    rows = [joint, *sub]
    mat[:, rows] = R[:, None] @ mat[:, rows]
