"""Tracker slots and the network's input features (paper Sec. 3).

Four tracked points, in this slot order everywhere (wire, features, datasets):

=====  ============  ======================
slot   name          canonical joint
=====  ============  ======================
0      HEAD          ``Joint.HEAD``
1      LEFT_HAND     ``Joint.LEFT_HAND``
2      RIGHT_HAND    ``Joint.RIGHT_HAND``
3      WAIST         ``Joint.PELVIS``
=====  ============  ======================

A tracker reports a world position (metres) and orientation (xyzw). Synthetic
trackers for training sit exactly on their joints and take the joint's world
rotation.

Features: every tracker position is moved into the *character frame* (subtract the
waist's X and Z, keep Y as height above the floor, turn by the inverse waist yaw),
together with its velocity in that frame, in m/s. Per tracker ``[px py pz vx vy vz]``,
4 x 6 = 24 values in slot order. The same function serves a whole clip and one live
frame, so training and serving cannot drift apart.
"""

from __future__ import annotations

from enum import IntEnum

import numpy as np
from numpy.typing import ArrayLike, NDArray

from posecast.geometry.rotations import (
    mat2quat,
    quat2r6d,
    quat2yaw,
    quat_apply,
    quat_conj,
    quat_mul,
    yaw2quat,
)
from posecast.skeleton import Joint


class TrackerSlot(IntEnum):
    HEAD = 0
    LEFT_HAND = 1
    RIGHT_HAND = 2
    WAIST = 3


NUM_TRACKERS = len(TrackerSlot)
FEATURES_PER_TRACKER = 6
NUM_FEATURES = NUM_TRACKERS * FEATURES_PER_TRACKER  # 24

TRACKER_JOINT: dict[TrackerSlot, Joint] = {
    TrackerSlot.HEAD: Joint.HEAD,
    TrackerSlot.LEFT_HAND: Joint.LEFT_HAND,
    TrackerSlot.RIGHT_HAND: Joint.RIGHT_HAND,
    TrackerSlot.WAIST: Joint.PELVIS,
}
TRACKER_JOINT_INDEX: tuple[int, ...] = tuple(int(TRACKER_JOINT[s]) for s in TrackerSlot)

FEATURE_NAMES: tuple[str, ...] = tuple(
    f"{slot.name}.{kind}{axis}" for slot in TrackerSlot for kind in ("p", "v") for axis in "xyz"
)

F = NDArray[np.float64]


def trackers_from_pose(world_mat: ArrayLike, world_pos: ArrayLike) -> tuple[F, F]:
    """Synthetic trackers from a posed skeleton.

    Args:
        world_mat: ``(..., 19, 3, 3)``; world_pos: ``(..., 19, 3)``.

    Returns:
        ``(positions (..., 4, 3), orientations (..., 4, 4) xyzw)`` in slot order.
    """
    wm = np.asarray(world_mat)
    wp = np.asarray(world_pos)
    idx = list(TRACKER_JOINT_INDEX)
    return wp[..., idx, :], mat2quat(wm[..., idx, :, :])


def tracker_features(pos: ArrayLike, prev_pos: ArrayLike, waist_quat: ArrayLike, fps: float) -> F:
    """Network input for one or many frames.

    Args:
        pos: ``(..., 4, 3)`` tracker positions this frame, metres.
        prev_pos: ``(..., 4, 3)`` the previous frame's positions (pass ``pos`` for
            the first frame: its velocity is zero).
        waist_quat: ``(..., 4)`` the waist tracker's orientation this frame.
        fps: frame rate the velocities are measured at (60 for the shipped model).

    Returns:
        ``(..., 24)`` features in :data:`FEATURE_NAMES` order.
    """
    p = np.asarray(pos, dtype=np.float64)
    pp = np.asarray(prev_pos, dtype=np.float64)
    inv_yaw = yaw2quat(-quat2yaw(waist_quat))[..., None, :]  # (..., 1, 4)
    origin = p[..., TrackerSlot.WAIST : TrackerSlot.WAIST + 1, :].copy()
    origin[..., 1] = 0.0
    local = quat_apply(inv_yaw, p - origin)
    vel = quat_apply(inv_yaw, (p - pp) * fps)
    return np.concatenate([local, vel], axis=-1).reshape(*p.shape[:-2], NUM_FEATURES)


def clip_features(pos: ArrayLike, quat: ArrayLike, fps: float) -> F:
    """Features for a whole clip of trackers ``(F, 4, 3)`` / ``(F, 4, 4)`` -> ``(F, 24)``."""
    p = np.asarray(pos, dtype=np.float64)
    prev = np.concatenate([p[:1], p[:-1]], axis=0)
    return tracker_features(p, prev, np.asarray(quat)[:, TrackerSlot.WAIST], fps)


def character_frame(waist_pos: ArrayLike, waist_quat: ArrayLike) -> tuple[F, F]:
    """The character frame of a waist pose: ``(origin (..., 3), inverse-yaw quat (..., 4))``.

    The origin is the waist's X and Z at floor height; the frame turns with the
    waist's heading only, so pitch and roll stay visible to the networks.
    """
    origin = np.array(waist_pos, dtype=np.float64, copy=True)
    origin[..., 1] = 0.0
    return origin, yaw2quat(-quat2yaw(waist_quat))


def to_character_frame(points: ArrayLike, waist_pos: ArrayLike, waist_quat: ArrayLike) -> F:
    """Points ``(..., K, 3)`` moved into the character frame of the waist ``(..., 3)/(..., 4)``."""
    origin, inv_yaw = character_frame(waist_pos, waist_quat)
    return quat_apply(inv_yaw[..., None, :], np.asarray(points) - origin[..., None, :])


def from_character_frame(points: ArrayLike, waist_pos: ArrayLike, waist_quat: ArrayLike) -> F:
    """Inverse of :func:`to_character_frame`: points ``(..., 3)`` back into the world,
    for a waist ``(..., 3)`` / ``(..., 4)`` that broadcasts against them."""
    origin, inv_yaw = character_frame(waist_pos, waist_quat)
    return quat_apply(quat_conj(inv_yaw), np.asarray(points)) + origin


def deyaw_quat(waist_quat: ArrayLike) -> F:
    """The waist rotation with its heading removed (what FK uses in the character frame)."""
    _, inv_yaw = character_frame(np.zeros(3), waist_quat)
    return quat_mul(inv_yaw, waist_quat)


# --- headset-only layout ("hmd3": head and both hands, no waist) -------------------------

HMD3_SLOTS: tuple[TrackerSlot, ...] = (
    TrackerSlot.HEAD,
    TrackerSlot.LEFT_HAND,
    TrackerSlot.RIGHT_HAND,
)
FEATURES_PER_TRACKER_HMD3 = 12  # position, velocity, 6D orientation
NUM_FEATURES_HMD3 = len(HMD3_SLOTS) * FEATURES_PER_TRACKER_HMD3  # 36

FEATURE_NAMES_HMD3: tuple[str, ...] = tuple(
    f"{slot.name}.{name}"
    for slot in HMD3_SLOTS
    for name in (*(f"{k}{a}" for k in ("p", "v") for a in "xyz"), *(f"r{i}" for i in range(6)))
)


def hmd3_features(pos: ArrayLike, prev_pos: ArrayLike, quat: ArrayLike, fps: float) -> F:
    """Network input of the headset-only model, for one or many frames.

    Everything is in the *head frame*: origin at the head's X and Z on the floor,
    turned by the inverse head yaw. Per tracker (head, left hand, right hand):
    position, velocity (m/s) and the orientation as 6D, 12 values, 36 in all. The
    orientations are what a waistless model has instead of the waist: the head's
    pitch and roll show leaning and bending, the hands' show the forearms.

    Args:
        pos, prev_pos: ``(..., 4, 3)`` or ``(..., 3, 3)`` positions (slot order; a
            waist slot, if present, is ignored).
        quat: ``(..., 4, 4)`` or ``(..., 3, 4)`` orientations, xyzw.
        fps: frame rate the velocities are measured at.

    Returns:
        ``(..., 36)`` in :data:`FEATURE_NAMES_HMD3` order.
    """
    p = np.asarray(pos, dtype=np.float64)[..., :3, :]
    pp = np.asarray(prev_pos, dtype=np.float64)[..., :3, :]
    q = np.asarray(quat, dtype=np.float64)[..., :3, :]
    origin, inv_yaw = character_frame(p[..., TrackerSlot.HEAD, :], q[..., TrackerSlot.HEAD, :])
    iy = inv_yaw[..., None, :]
    local = quat_apply(iy, p - origin[..., None, :])
    vel = quat_apply(iy, (p - pp) * fps)
    rot = quat2r6d(quat_mul(iy, q))
    feats = np.concatenate([local, vel, rot], axis=-1)  # (..., 3, 12)
    return feats.reshape(*p.shape[:-2], NUM_FEATURES_HMD3)
