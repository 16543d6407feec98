"""Rotation helpers in numpy, batched over any leading shape.

Glossary: ``quat`` is a quaternion xyzw (scalar last), ``mat`` a 3x3 rotation
matrix, ``euler`` angles in radians about the axes of an order such as ``"ZYX"``,
meaning ``Rz(a0) @ Ry(a1) @ Rx(a2)`` (BVH's channel order). Converters are named
``X2Y`` and take ``(..., k)`` inputs.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from numpy.typing import ArrayLike, NDArray

F64 = NDArray[np.float64]
_AXIS = {"X": 0, "Y": 1, "Z": 2}


def quat_normalize(q: ArrayLike) -> F64:
    a = np.asarray(q, dtype=np.float64)
    out: F64 = a / np.linalg.norm(a, axis=-1, keepdims=True)
    return out


def quat_mul(a: ArrayLike, b: ArrayLike) -> F64:
    """Hamilton product ``a * b`` (apply ``b``, then ``a``)."""
    a = np.asarray(a, dtype=np.float64)
    b = np.asarray(b, dtype=np.float64)
    x1, y1, z1, w1 = a[..., 0], a[..., 1], a[..., 2], a[..., 3]
    x2, y2, z2, w2 = b[..., 0], b[..., 1], b[..., 2], b[..., 3]
    out = np.empty(np.broadcast_shapes(a.shape, b.shape))  # filled in place: no stacking
    out[..., 0] = w1 * x2 + x1 * w2 + y1 * z2 - z1 * y2
    out[..., 1] = w1 * y2 - x1 * z2 + y1 * w2 + z1 * x2
    out[..., 2] = w1 * z2 + x1 * y2 - y1 * x2 + z1 * w2
    out[..., 3] = w1 * w2 - x1 * x2 - y1 * y2 - z1 * z2
    return out


def quat2mat(q: ArrayLike) -> F64:
    """``(..., 4)`` xyzw -> ``(..., 3, 3)`` (normalises first)."""
    x, y, z, w = np.moveaxis(quat_normalize(q), -1, 0)
    return np.stack(
        [
            np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)], -1),
            np.stack([2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)], -1),
            np.stack([2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)], -1),
        ],
        axis=-2,
    )


def mat2quat(m: ArrayLike) -> F64:
    """``(..., 3, 3)`` -> ``(..., 4)`` xyzw with ``w >= 0`` (Shepperd's method)."""
    r = np.asarray(m, dtype=np.float64)
    m00, m11, m22 = r[..., 0, 0], r[..., 1, 1], r[..., 2, 2]
    # Four candidate forms; each is accurate where its squared component is largest.
    cand = np.stack(
        [
            np.stack(
                [
                    1 + m00 - m11 - m22,
                    r[..., 0, 1] + r[..., 1, 0],
                    r[..., 0, 2] + r[..., 2, 0],
                    r[..., 2, 1] - r[..., 1, 2],
                ],
                -1,
            ),
            np.stack(
                [
                    r[..., 0, 1] + r[..., 1, 0],
                    1 - m00 + m11 - m22,
                    r[..., 1, 2] + r[..., 2, 1],
                    r[..., 0, 2] - r[..., 2, 0],
                ],
                -1,
            ),
            np.stack(
                [
                    r[..., 0, 2] + r[..., 2, 0],
                    r[..., 1, 2] + r[..., 2, 1],
                    1 - m00 - m11 + m22,
                    r[..., 1, 0] - r[..., 0, 1],
                ],
                -1,
            ),
            np.stack(
                [
                    r[..., 2, 1] - r[..., 1, 2],
                    r[..., 0, 2] - r[..., 2, 0],
                    r[..., 1, 0] - r[..., 0, 1],
                    1 + m00 + m11 + m22,
                ],
                -1,
            ),
        ],
        axis=-2,
    )  # (..., 4 candidates, 4) fmt: skip
    diag = np.stack([m00, m11, m22, m00 + m11 + m22], -1)
    best = np.argmax(diag, axis=-1)[..., None, None]
    q = quat_normalize(np.take_along_axis(cand, best, axis=-2)[..., 0, :])
    return np.where(q[..., 3:] < 0, -q, q)


def axis_angle2mat(axis: str, angle: ArrayLike) -> F64:
    """Rotation by ``angle`` radians about the world ``axis`` (``"X"``, ``"Y"``, ``"Z"``)."""
    a = np.asarray(angle, dtype=np.float64)
    c, s = np.cos(a), np.sin(a)
    o, z = np.ones_like(a), np.zeros_like(a)
    rows = {
        "X": [[o, z, z], [z, c, -s], [z, s, c]],
        "Y": [[c, z, s], [z, o, z], [-s, z, c]],
        "Z": [[c, -s, z], [s, c, z], [z, z, o]],
    }[axis]
    return np.stack([np.stack(r, -1) for r in rows], -2)


def euler2mat(angles: ArrayLike, order: str) -> F64:
    """``(..., k)`` radians about the axes of ``order`` -> ``(..., 3, 3)``, left to right."""
    a = np.asarray(angles, dtype=np.float64)
    out = np.broadcast_to(np.eye(3), (*a.shape[:-1], 3, 3)).copy()
    for i, axis in enumerate(order):
        out = out @ axis_angle2mat(axis, a[..., i])
    return out


def mat2euler_zyx(m: ArrayLike) -> F64:
    """``(..., 3, 3)`` -> ``(..., 3)`` radians with ``m = Rz(a0) @ Ry(a1) @ Rx(a2)``."""
    r = np.asarray(m, dtype=np.float64)
    sy = np.clip(-r[..., 2, 0], -1.0, 1.0)
    locked = np.abs(sy) > 1.0 - 1e-9  # gimbal lock: put everything into Z
    a0 = np.where(
        locked, np.arctan2(-r[..., 0, 1], r[..., 1, 1]), np.arctan2(r[..., 1, 0], r[..., 0, 0])
    )
    a2 = np.where(locked, 0.0, np.arctan2(r[..., 2, 1], r[..., 2, 2]))
    return np.stack([a0, np.arcsin(sy), a2], axis=-1)


def vecs2mat(a: ArrayLike, b: ArrayLike) -> F64:
    """The smallest rotation turning direction ``a (..., 3)`` onto ``b (..., 3)``."""
    u = np.asarray(a, dtype=np.float64)
    v = np.asarray(b, dtype=np.float64)
    u = u / np.maximum(np.linalg.norm(u, axis=-1, keepdims=True), 1e-12)
    v = v / np.maximum(np.linalg.norm(v, axis=-1, keepdims=True), 1e-12)
    w = 1.0 + (u * v).sum(-1, keepdims=True)
    q = np.concatenate([np.cross(u, v), w], axis=-1)  # (..., 4), half-way quaternion
    # Opposite vectors: any axis perpendicular to u, turned by 180 degrees.
    perp = np.cross(u, np.where(np.abs(u[..., :1]) < 0.9, [1.0, 0, 0], [0, 1.0, 0]))
    flip = np.concatenate([perp, np.zeros_like(w)], axis=-1)
    q = np.where(w < 1e-9, flip, q)
    return quat2mat(q)


def kabsch(rest: ArrayLike, now: ArrayLike) -> F64:
    """The rotation ``R`` that best maps vectors ``rest (..., K, 3)`` onto ``now (..., K, 3)``.

    Least squares over the K pairs (SVD, reflections excluded); ``K >= 2`` vectors
    that are not parallel fix all three axes.
    """
    h = np.swapaxes(np.asarray(rest, dtype=np.float64), -1, -2) @ np.asarray(now, dtype=np.float64)
    u, _, vt = np.linalg.svd(h)  # h = (3, K) @ (K, 3)
    d = np.sign(np.linalg.det(np.swapaxes(vt, -1, -2) @ np.swapaxes(u, -1, -2)))
    fix = np.broadcast_to(np.eye(3), h.shape).copy()
    fix[..., 2, 2] = d
    out: F64 = np.swapaxes(vt, -1, -2) @ fix @ np.swapaxes(u, -1, -2)
    return out


def quat_nlerp(q0: ArrayLike, q1: ArrayLike, t: ArrayLike) -> F64:
    """Normalised linear interpolation on the shorter arc (slerp is not needed between
    neighbouring mocap frames: the angles are small)."""
    a = np.asarray(q0, dtype=np.float64)
    b = np.asarray(q1, dtype=np.float64)
    b = np.where((a * b).sum(-1, keepdims=True) < 0, -b, b)
    w = np.asarray(t, dtype=np.float64)[..., None]
    return quat_normalize(a * (1 - w) + b * w)


def fk(
    local_mat: ArrayLike, root_pos: ArrayLike, offsets: ArrayLike, parents: Sequence[int]
) -> tuple[F64, F64]:
    """Forward kinematics: local rotations ``(..., J, 3, 3)``, root ``(..., 3)`` and
    offsets ``(J, 3)`` or ``(..., J, 3)`` -> world rotations ``(..., J, 3, 3)`` and
    positions ``(..., J, 3)``.

    Joint 0 is the root; its local rotation is its world rotation. Parents first.
    """
    loc = np.asarray(local_mat, dtype=np.float64)
    off = np.asarray(offsets, dtype=np.float64)
    world = np.empty_like(loc)
    pos = np.empty((*loc.shape[:-2], 3))
    for j, p in enumerate(parents):
        if p < 0:
            world[..., j, :, :] = loc[..., j, :, :]
            pos[..., j, :] = root_pos
        else:
            world[..., j, :, :] = world[..., p, :, :] @ loc[..., j, :, :]
            bone = np.einsum("...ab,...b->...a", world[..., p, :, :], off[..., j, :])
            pos[..., j, :] = pos[..., p, :] + bone
    return world, pos
