"""Rotation conversions in numpy, batched over any leading shape.

Glossary (after fairmotion):

* ``quat`` unit quaternion, **xyzw** (scalar last), shape ``(..., 4)``
* ``mat``  rotation matrix acting on column vectors, ``(..., 3, 3)``
* ``r6d``  the first two matrix columns, concatenated ``[c0, c1]``, ``(..., 6)``
  (Zhou et al. 2019, the representation the networks predict)
* ``aa``   axis-angle, axis times angle in radians, ``(..., 3)``
* ``euler`` angles in radians with an axis order such as ``"ZYX"``, meaning
  ``R = Rz(a0) @ Ry(a1) @ Rx(a2)`` (intrinsic; the BVH channel convention)

Converters are named ``X2Y`` and never mutate their input.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

F = NDArray[np.float64]

_AXES = {"X": 0, "Y": 1, "Z": 2}
_EPS = 1e-12


_EYE3 = np.eye(3)


def _arr(x: ArrayLike) -> NDArray[np.float64]:
    """Float64 view or copy of ``x`` (the reference math runs in double precision)."""
    return np.asarray(x, dtype=np.float64)


def normalize(v: ArrayLike, axis: int = -1) -> F:
    """``v`` scaled to unit length along ``axis`` (zero vectors stay zero)."""
    a = _arr(v)
    n = np.linalg.norm(a, axis=axis, keepdims=True)
    out: F = a / np.maximum(n, _EPS)
    return out


# --- quaternions -----------------------------------------------------------------


def quat_identity(shape: tuple[int, ...] = ()) -> NDArray[np.float64]:
    """Identity quaternions of the given leading shape."""
    q = np.zeros((*shape, 4))
    q[..., 3] = 1.0
    return q


def quat_normalize(q: ArrayLike) -> F:
    return normalize(q)


def quat_conj(q: ArrayLike) -> F:
    """Conjugate, which is the inverse for unit quaternions."""
    a = _arr(q).copy()
    a[..., :3] *= -1.0
    return a


def quat_mul(a: ArrayLike, b: ArrayLike) -> F:
    """Hamilton product ``a * b`` (apply ``b`` first, then ``a``)."""
    qa, qb = _arr(a), _arr(b)
    ax, ay, az, aw = np.moveaxis(qa, -1, 0)
    bx, by, bz, bw = np.moveaxis(qb, -1, 0)
    return np.stack(
        [
            aw * bx + ax * bw + ay * bz - az * by,
            aw * by - ax * bz + ay * bw + az * bx,
            aw * bz + ax * by - ay * bx + az * bw,
            aw * bw - ax * bx - ay * by - az * bz,
        ],
        axis=-1,
    )


def quat_apply(q: ArrayLike, v: ArrayLike) -> F:
    """Rotate vectors ``v (..., 3)`` by quaternions ``q (..., 4)``."""
    qa, va = _arr(q), _arr(v)
    x, y, z, w = qa[..., 0:1], qa[..., 1:2], qa[..., 2:3], qa[..., 3:4]
    vx, vy, vz = va[..., 0:1], va[..., 1:2], va[..., 2:3]
    # t = 2 u x v, then v + w t + u x t (np.cross is slow on small stacks)
    tx, ty, tz = 2.0 * (y * vz - z * vy), 2.0 * (z * vx - x * vz), 2.0 * (x * vy - y * vx)
    out: F = np.concatenate(
        [
            vx + w * tx + (y * tz - z * ty),
            vy + w * ty + (z * tx - x * tz),
            vz + w * tz + (x * ty - y * tx),
        ],
        axis=-1,
    )
    return out


def quat_slerp(q0: ArrayLike, q1: ArrayLike, t: ArrayLike) -> F:
    """Spherical interpolation, taking the short way; ``t`` broadcasts as ``(...,)``."""
    a, b = quat_normalize(q0), quat_normalize(q1)
    tt = _arr(t)[..., None]
    d = np.sum(a * b, axis=-1, keepdims=True)
    b = np.where(d < 0.0, -b, b)
    d = np.abs(d)
    theta = np.arccos(np.clip(d, -1.0, 1.0))
    s = np.sin(theta)
    small = s < 1e-6
    safe_s = np.where(small, 1.0, s)
    w0 = np.where(small, 1.0 - tt, np.sin((1.0 - tt) * theta) / safe_s)
    w1 = np.where(small, tt, np.sin(tt * theta) / safe_s)
    return quat_normalize(w0 * a + w1 * b)


def quat2mat(q: ArrayLike) -> F:
    """Unit quaternion (xyzw) to rotation matrix."""
    qa = quat_normalize(q)
    x, y, z, w = np.moveaxis(qa, -1, 0)
    xx, yy, zz = x * x, y * y, z * z
    xy, xz, yz = x * y, x * z, y * z
    wx, wy, wz = w * x, w * y, w * z
    m = np.stack(
        [
            1 - 2 * (yy + zz), 2 * (xy - wz), 2 * (xz + wy),
            2 * (xy + wz), 1 - 2 * (xx + zz), 2 * (yz - wx),
            2 * (xz - wy), 2 * (yz + wx), 1 - 2 * (xx + yy),
        ],
        axis=-1,
    )  # fmt: skip
    return m.reshape(*qa.shape[:-1], 3, 3)


def mat2quat(m: ArrayLike) -> F:
    """Rotation matrix to unit quaternion (xyzw) with ``w >= 0`` (Shepperd's method)."""
    R = _arr(m)
    m00, m11, m22 = R[..., 0, 0], R[..., 1, 1], R[..., 2, 2]
    tr = m00 + m11 + m22
    cand = np.stack(
        [
            np.stack([R[..., 2, 1] - R[..., 1, 2], R[..., 0, 2] - R[..., 2, 0],
                      R[..., 1, 0] - R[..., 0, 1], 1 + tr], -1),
            np.stack([1 + m00 - m11 - m22, R[..., 0, 1] + R[..., 1, 0],
                      R[..., 0, 2] + R[..., 2, 0], R[..., 2, 1] - R[..., 1, 2]], -1),
            np.stack([R[..., 0, 1] + R[..., 1, 0], 1 - m00 + m11 - m22,
                      R[..., 1, 2] + R[..., 2, 1], R[..., 0, 2] - R[..., 2, 0]], -1),
            np.stack([R[..., 0, 2] + R[..., 2, 0], R[..., 1, 2] + R[..., 2, 1],
                      1 - m00 - m11 + m22, R[..., 1, 0] - R[..., 0, 1]], -1),
        ],
        axis=-2,
    )  # (..., 4 candidates, 4)  # fmt: skip
    choice = np.argmax(np.stack([tr, m00, m11, m22], -1), axis=-1)
    q = np.take_along_axis(cand, choice[..., None, None], axis=-2)[..., 0, :]
    q = quat_normalize(q)
    return np.where(q[..., 3:] < 0, -q, q)


# --- 6D ----------------------------------------------------------------------------


def mat2r6d(m: ArrayLike) -> F:
    """First two columns of ``m``, as ``[c0, c1]``: ``(..., 3, 3) -> (..., 6)``."""
    R = _arr(m)
    return np.concatenate([R[..., :, 0], R[..., :, 1]], axis=-1)


def r6d2mat(d: ArrayLike) -> F:
    """6D to rotation matrix by Gram-Schmidt; any 6-vector maps to a valid rotation."""
    a = _arr(d)
    b1 = normalize(a[..., 0:3])
    a2 = a[..., 3:6]
    b2 = normalize(a2 - np.sum(b1 * a2, axis=-1, keepdims=True) * b1)
    b3 = np.cross(b1, b2)
    return np.stack([b1, b2, b3], axis=-1)


def quat2r6d(q: ArrayLike) -> F:
    return mat2r6d(quat2mat(q))


def r6d2quat(d: ArrayLike) -> F:
    return mat2quat(r6d2mat(d))


# --- axis-angle -------------------------------------------------------------------


def aa2quat(aa: ArrayLike) -> F:
    a = _arr(aa)
    angle = np.linalg.norm(a, axis=-1, keepdims=True)
    half = 0.5 * angle
    # sin(half)/angle, with its limit 1/2 at zero
    k = np.where(angle < 1e-8, 0.5 - angle**2 / 48.0, np.sin(half) / np.maximum(angle, _EPS))
    return np.concatenate([a * k, np.cos(half)], axis=-1)


def quat2aa(q: ArrayLike) -> F:
    qa = quat_normalize(q)
    qa = np.where(qa[..., 3:] < 0, -qa, qa)
    s = np.linalg.norm(qa[..., :3], axis=-1, keepdims=True)
    angle = 2.0 * np.arctan2(s, qa[..., 3:])
    k = np.where(s < 1e-8, 2.0, angle / np.maximum(s, _EPS))
    return qa[..., :3] * k


def aa2mat(aa: ArrayLike) -> F:
    return quat2mat(aa2quat(aa))


def axis_angle_mat(axis: ArrayLike, angle: ArrayLike) -> F:
    """Rotations ``(B, 3, 3)`` by ``angle (B,)`` radians about unit ``axis (B, 3)``
    (Rodrigues' formula; cheaper than :func:`aa2mat` when the axis is unit already)."""
    u = _arr(axis)
    t = _arr(angle)
    c, s = np.cos(t)[:, None, None], np.sin(t)[:, None, None]
    x, y, z = u[:, 0], u[:, 1], u[:, 2]
    zero = np.zeros_like(x)
    k = np.stack([zero, -z, y, z, zero, -x, -y, x, zero], axis=-1).reshape(-1, 3, 3)
    out: F = c * _EYE3 + s * k + (1.0 - c) * (u[:, :, None] * u[:, None, :])
    return out


def mat2aa(m: ArrayLike) -> F:
    return quat2aa(mat2quat(m))


# --- Euler angles (BVH channels) -----------------------------------------------------


def axis_mat(axis: str, angle: ArrayLike) -> F:
    """Rotation about one principal axis ``"X"|"Y"|"Z"`` by ``angle`` radians."""
    t = _arr(angle)
    c, s = np.cos(t), np.sin(t)
    o, z = np.ones_like(t), np.zeros_like(t)
    if axis == "X":
        rows = [o, z, z, z, c, -s, z, s, c]
    elif axis == "Y":
        rows = [c, z, s, z, o, z, -s, z, c]
    elif axis == "Z":
        rows = [c, -s, z, s, c, z, z, z, o]
    else:
        raise ValueError(f"unknown axis {axis!r}")
    return np.stack(rows, axis=-1).reshape(*t.shape, 3, 3)


def euler2mat(angles: ArrayLike, order: str) -> F:
    """``angles (..., k)`` radians about the axes in ``order`` (k letters) to matrices.

    ``order="ZYX"`` gives ``Rz(a0) @ Ry(a1) @ Rx(a2)``. Any number of axes works,
    so BVH files with unusual channel lists still read.
    """
    a = _arr(angles)
    if a.shape[-1] != len(order):
        raise ValueError(f"{a.shape[-1]} angles for order {order!r}")
    out = np.broadcast_to(np.eye(3), (*a.shape[:-1], 3, 3)).copy()
    for i, ax in enumerate(order):
        out = out @ axis_mat(ax, a[..., i])
    return out


def mat2euler(m: ArrayLike, order: str) -> F:
    """Inverse of :func:`euler2mat` for the six Tait-Bryan orders (three distinct axes).

    The middle angle lies in ``[-pi/2, pi/2]``. At gimbal lock the last angle is 0.
    """
    if len(order) != 3 or len(set(order)) != 3 or not set(order) <= set(_AXES):
        raise ValueError(f"order must be three distinct axes, got {order!r}")
    R = _arr(m)
    i, j, k = (_AXES[c] for c in order)
    sign = 1.0 if (j - i) % 3 == 1 else -1.0
    # cos(b) from the other two entries of row i, and b by arctan2: arcsin(sin b) loses
    # half the digits near +-pi/2, exactly where the lock test needs them.
    cb = np.hypot(R[..., i, i], R[..., i, j])
    b = np.arctan2(sign * R[..., i, k], cb)
    # Locked when a and c turn about the same axis to within 1e-8 rad. A looser test
    # (such as |sin b| > 1 - 1e-9, cos b up to 4.5e-5) throws that much of c away.
    locked = cb < 1e-8
    a = np.arctan2(-sign * R[..., j, k], R[..., k, k])
    c = np.arctan2(-sign * R[..., i, j], R[..., i, i])
    # Gimbal lock: a and c turn about the same axis; put it all in a.
    a_locked = np.arctan2(sign * R[..., k, j], R[..., j, j])
    a = np.where(locked, a_locked, a)
    c = np.where(locked, 0.0, c)
    return np.stack([a, b, c], axis=-1)


# --- construction helpers ------------------------------------------------------------


def vecs2quat(a: ArrayLike, b: ArrayLike) -> F:
    """Smallest rotation taking direction ``a`` onto direction ``b`` (both ``(..., 3)``).

    For opposite vectors any perpendicular axis is used.
    """
    ua, ub = normalize(a), normalize(b)
    d = np.sum(ua * ub, axis=-1, keepdims=True)
    axis = np.cross(ua, ub)
    q = np.concatenate([axis, 1.0 + d], axis=-1)
    opposite = (1.0 + d[..., 0]) < 1e-9
    if np.any(opposite):
        # a perpendicular to ua: cross with whichever principal axis is least aligned
        helper = np.where(
            np.abs(ua[..., :1]) < 0.9, np.array([1.0, 0.0, 0.0]), np.array([0.0, 1.0, 0.0])
        )
        perp = normalize(np.cross(ua, helper))
        q = np.where(opposite[..., None], np.concatenate([perp, np.zeros_like(d)], -1), q)
    return quat_normalize(q)


def yaw2quat(yaw: ArrayLike) -> F:
    """Rotation about +Y by ``yaw`` radians."""
    y = _arr(yaw)
    return np.stack([np.zeros_like(y), np.sin(0.5 * y), np.zeros_like(y), np.cos(0.5 * y)], axis=-1)


def quat2yaw(q: ArrayLike) -> F:
    """Heading of a rotation: the angle about +Y of its rotated +Z (forward) axis."""
    fwd = quat_apply(q, np.array([0.0, 0.0, 1.0]))
    return np.arctan2(fwd[..., 0], fwd[..., 2])
