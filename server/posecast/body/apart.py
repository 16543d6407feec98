"""Legs apart: the display contact IK never draws one leg through the other.

A foot held where its contact began (``ik.ContactIK``), or blending back from there,
is where the network's foot was some frames ago. When the other leg swings past it
(a narrow walk, a dancer's crossing step) the held leg and the swinging one can meet:
the network's own legs kept clear of each other on every validation frame, and the
contact IK alone put them through each other on 0.5 % of them (docs/evaluation.md,
"Legs apart"). A foot cannot stay planted where the other leg passes, so such a foot
gives way: its ankle target moves from the contact IK's back toward the network's own
ankle, by the least share ``s`` in ``[0, 1]`` that keeps the legs as far apart as the
network had them (or at most :data:`MAX_OVERLAP_M` into each other), to within a
millimetre (the refinement of ``s`` is linear, the knee's path is not). ``s`` is 0 when
nothing meets, and it grows continuously as the legs draw together, so nothing jumps.
A leg the contact IK does not hold keeps what the contact IK made of it.

The legs are capsules around thigh, shin and foot (hip-knee, knee-ankle, ankle-toe)
of :data:`RADII_M`. Pure numpy on world positions and rotations ``(B, 19, ...)``.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from posecast.body.batch_fk import fk32
from posecast.body.ik import LEGS, THIGHS_SHINS, apply_leg_ik, two_bone_ik
from posecast.geometry.rotations import mat2quat, quat2mat
from posecast.skeleton import NUM_JOINTS

F64 = NDArray[np.float64]

# Capsule radii of thigh, shin and foot (metres, the reference body).
RADII_M = (0.05, 0.04, 0.03)
# How far two capsules may run into each other before a held foot gives way (when the
# network's own legs stood further apart): legs may touch, not pass. 0.02 m, chosen on
# the validation split among 0, 0.02 and 0.04 (docs/evaluation.md, "Legs apart").
MAX_OVERLAP_M = 0.02
SHARES = 17  # shares tried: 0, 1/16, ..., 1 of the way back to the network's ankles
# A foot whose shown ankle is further than this from the network's is one the contact
# IK holds (the network's legs are rebuilt in float32 far from the origin: 1e-6 m off).
HELD_M = 1e-4

_CHAINS = np.array([[int(j) for j in leg] for leg in LEGS])  # (2, 4): hip, knee, ankle, toe
# The nine pairs (left segment i, right segment k) and the radii they sum to.
_PAIRS_I = np.repeat(np.arange(3), 3)
_PAIRS_K = np.tile(np.arange(3), 3)
_RSUM = np.asarray(RADII_M)[_PAIRS_I] + np.asarray(RADII_M)[_PAIRS_K]
_ANKLES = [int(leg[2]) for leg in LEGS]
_LEG_JOINTS = tuple(int(j) for leg in LEGS for j in leg)


def overlap(pos: NDArray[np.floating]) -> F64:
    """How deep the two legs' capsules run into each other, per pose: the largest
    ``r_i + r_k - distance`` over the nine segment pairs (metres; negative when
    apart). ``(..., 19, 3)`` -> ``(...,)``."""
    p = np.asarray(pos, np.float64)
    return _overlap_legs(p[..., _CHAINS[0], :], p[..., _CHAINS[1], :])


def _overlap_legs(left: F64, right: F64) -> F64:
    """:func:`overlap` of the legs' joints alone: hip, knee, ankle, toe ``(..., 4, 3)``
    of each leg."""
    a0, a1 = left[..., _PAIRS_I, :], left[..., _PAIRS_I + 1, :]  # (..., 9, 3)
    b0, b1 = right[..., _PAIRS_K, :], right[..., _PAIRS_K + 1, :]
    out: F64 = np.max(_RSUM - _segments_apart(a0, a1, b0, b1), axis=-1)
    return out


def _segments_apart(a0: F64, a1: F64, b0: F64, b1: F64) -> F64:
    """Closest distance between segments ``a0-a1`` and ``b0-b1``, ``(..., 3)`` -> ``(...,)``
    (the clamped closest-point parameters of both lines)."""
    u, v, w = a1 - a0, b1 - b0, a0 - b0
    uu, vv, uv = (u * u).sum(-1), (v * v).sum(-1), (u * v).sum(-1)
    uw, vw = (u * w).sum(-1), (v * w).sum(-1)
    tiny = 1e-12
    det = uu * vv - uv * uv
    s = np.clip(np.where(det > tiny, (uv * vw - vv * uw) / np.maximum(det, tiny), 0.0), 0, 1)
    t = np.clip((uv * s + vw) / np.maximum(vv, tiny), 0.0, 1.0)
    # With t clamped, the best s on a's segment for that t.
    s = np.clip((uv * t - uw) / np.maximum(uu, tiny), 0.0, 1.0)
    gap = (a0 + u * s[..., None]) - (b0 + v * t[..., None])
    return np.asarray(np.sqrt((gap * gap).sum(-1)), np.float64)


def keep_apart(
    world_mat: F64,
    world_pos: F64,
    net_mat: NDArray[np.floating],
    net_pos: NDArray[np.floating],
    max_overlap_m: float = MAX_OVERLAP_M,
    deep: NDArray[np.floating] | None = None,
) -> NDArray[np.bool_]:
    """Where the contact IK's pose ``world_mat (B, 19, 3, 3)``, ``world_pos (B, 19, 3)``
    has its legs deeper into each other than ``max(overlap(net_pos), max_overlap_m)``,
    solve its held legs again from the network's own legs (``net_mat``, ``net_pos``:
    the pose before the contact IK, whose hips are the same) toward ankle targets moved
    from the contact IK's back toward the network's ankles by the least share that
    keeps them apart, in place. The same solve as the contact IK's
    (:func:`~posecast.body.ik.apply_leg_ik`, knees bent toward the network's
    thighs' forward axes), so a share of 0 is the contact IK's pose and 1 the
    network's legs (knees forward). The share: the first of :data:`SHARES` evenly
    spaced ones that keeps the legs apart (all tried in one batch), refined linearly
    between it and the one before, then by one step of false position. A held foot is
    one whose ankle is more than :data:`HELD_M` from the network's; a leg not held
    keeps what the contact IK made of it. ``deep``: :func:`overlap` of ``world_pos``,
    when the caller has it. Returns which poses moved."""
    deep = overlap(world_pos) if deep is None else np.asarray(deep, np.float64)
    rows = np.flatnonzero(deep > max_overlap_m)
    allowed = np.maximum(overlap(net_pos[rows]), max_overlap_m)
    ik_ankles = world_pos[rows][:, _ANKLES]
    toward = np.asarray(net_pos, np.float64)[rows][:, _ANKLES] - ik_ankles  # (R, 2, 3)
    held = np.linalg.norm(toward, axis=-1) > HELD_M  # (R, 2): feet the contact IK moved
    meet = (deep[rows] > allowed) & held.any(axis=1)
    rows, allowed, ik_ankles, toward, held = (
        rows[meet],
        allowed[meet],
        ik_ankles[meet],
        toward[meet],
        held[meet],
    )
    moved = np.zeros(len(world_pos), np.bool_)
    if not len(rows):
        return moved
    n_pos = np.asarray(net_pos, np.float64)[rows]
    n_mat = np.asarray(net_mat, np.float64)[rows]
    pos, mat = world_pos[rows], world_mat[rows]

    grid = np.linspace(0.0, 1.0, SHARES)
    trial = _legs_at(
        n_pos, n_mat, pos, ik_ankles, toward, held, np.broadcast_to(grid, (len(rows), SHARES))
    )
    over = _overlap_legs(trial[..., 0, :, :], trial[..., 1, :, :]) - allowed[:, None]  # (R, S)
    clear = over <= 0.0
    hi = np.where(clear.any(axis=1), np.argmax(clear, axis=1), SHARES - 1)
    lo = np.maximum(hi - 1, 0)
    r = np.arange(len(rows))
    f_lo, f_hi = over[r, lo], over[r, hi]
    frac = np.where(f_lo > f_hi, np.clip(f_lo / np.maximum(f_lo - f_hi, 1e-12), 0, 1), 1.0)
    share = np.where(hi > 0, grid[lo] + frac * (grid[hi] - grid[lo]), 0.0)
    # The refinement is linear, the knee's path is not: where the refined share leaves
    # the legs past the allowance, one more step of false position between it and the
    # grid's share that cleared (continuous in the pose, unlike falling back to it).
    refined = _legs_at(n_pos, n_mat, pos, ik_ankles, toward, held, share[:, None])[:, 0]
    f_mid = _overlap_legs(refined[:, 0], refined[:, 1]) - allowed
    past = (f_mid > 0.0) & (f_hi <= 0.0) & (hi > 0)
    step = f_mid / np.maximum(f_mid - f_hi, 1e-12)
    share = np.where(past, share + np.clip(step, 0.0, 1.0) * (grid[hi] - share), share)
    for side in range(2):
        on = held[:, side]
        if not on.any():
            continue
        joints = _CHAINS[side]
        p, m = pos[on], mat[on]
        p[:, joints], m[:, joints] = n_pos[on][:, joints], n_mat[on][:, joints]
        target = ik_ankles[on] + share[on, None, None] * toward[on]
        only = np.zeros((int(on.sum()), 2), np.bool_)
        only[:, side] = True
        apply_leg_ik(m, p, target, only)
        pos[on], mat[on] = p, m
    world_pos[rows], world_mat[rows] = pos, mat
    moved[rows] = True
    return moved


def _legs_at(
    n_pos: F64,
    n_mat: F64,
    pos: F64,
    ik_ankles: F64,
    toward: F64,
    held: NDArray[np.bool_],
    share: F64,
) -> F64:
    """Both legs' hip, knee, ankle and toe ``(R, S, 2, 4, 3)`` at each share ``(R, S)``:
    a held leg solved from the network's (``n_pos``, its thigh's forward axis from
    ``n_mat``) toward the contact IK's ankle moved ``share`` of the way to the
    network's, positions only; a free leg as the contact IK left it (``pos``)."""
    legs = np.repeat(pos[:, None][:, :, _CHAINS], share.shape[1], axis=1)  # (R, S, 2, 4, 3)
    net = n_pos[:, _CHAINS]  # (R, 2, 4, 3)
    for side in np.flatnonzero(held.any(axis=0)).tolist():
        hip, knee, ankle, toe = (net[:, None, side, k] for k in range(4))  # (R, 1, 3)
        hint = n_mat[:, None, _CHAINS[side, 0], :, 2]  # the thigh's forward axis
        target = ik_ankles[:, None, side] + share[..., None] * toward[:, None, side]
        h, k, a, t, d = np.broadcast_arrays(hip, knee, ankle, target, hint)
        k2, a2 = two_bone_ik(h, k, a, t, d)
        on = held[:, side, None, None]
        legs[:, :, side, 0] = np.where(on, hip, legs[:, :, side, 0])
        legs[:, :, side, 1] = np.where(on, k2, legs[:, :, side, 1])
        legs[:, :, side, 2] = np.where(on, a2, legs[:, :, side, 2])
        legs[:, :, side, 3] = np.where(on, a2 + (toe - ankle), legs[:, :, side, 3])
    return legs


def keep_apart_quat(
    positions: NDArray[np.float32],
    rotations: NDArray[np.float32],
    rot6d: NDArray[np.float32],
    root_mat: NDArray[np.float32],
    root_pos: NDArray[np.float32],
) -> None:
    """:func:`keep_apart` on the shown poses after the display contact IK, in place:
    positions ``(E, 19, 3)`` and world rotations ``(E, 19, 4)`` xyzw float32 (the
    thighs' and shins' change); the network's own legs come from its rotations
    ``rot6d (E, 108)`` on the same pelvis (float32 FK), for the poses whose legs meet."""
    deep = overlap(positions)
    rows = np.flatnonzero(deep > MAX_OVERLAP_M)
    if not len(rows):
        return
    mat32, pos32 = fk32(rot6d[rows], root_mat[rows], root_pos[rows], True, _LEG_JOINTS)
    assert mat32 is not None
    # Only the legs' rows of fk32's output are defined (and all keep_apart reads).
    legs = list(_LEG_JOINTS)
    net_mat, net_pos = np.zeros((len(rows), NUM_JOINTS, 3, 3)), np.zeros((len(rows), NUM_JOINTS, 3))
    net_mat[:, legs], net_pos[:, legs] = mat32[:, legs], pos32[:, legs]
    pos = positions[rows].astype(np.float64)
    mat = quat2mat(rotations[rows].astype(np.float64))
    keep_apart(mat, pos, net_mat, net_pos, deep=deep[rows])
    positions[rows] = pos
    rotations[np.ix_(rows, THIGHS_SHINS)] = mat2quat(mat[:, THIGHS_SHINS])
