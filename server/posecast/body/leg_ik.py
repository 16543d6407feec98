"""The lower-body pass of tracker sets: feet on positional foot trackers, knees toward
positional knee trackers (numpy, batched).

A tracker set's foot tracker reports where the ankle is; the network only conditions on
it. This pass, the legs' counterpart of :mod:`posecast.body.upper_ik`, runs on
the shown poses after the contact IK and the floor pass (a tracked foot is where its
tracker says, floor or not) and changes rotations only, keeping every bone's length
and FK consistency:

* a leg whose **foot** is positional: a two-bone solve (thigh, shin) from the hip puts
  the ankle on the tracker, the knee in the plane of hip, target and a pole: the knee
  tracker where that is positional too, else the network's own knee (on its side of
  the hip-ankle line, so no flips); the foot's world rotation becomes the tracker's
  (the toe follows);
* a leg whose **knee** alone is positional: the thigh swings to point at the knee
  tracker, carrying shin and foot.

Out of reach, the leg reaches straight at the target and the pose is flagged as the
upper-body pass flags it (``reach_limited``). Inertial and absent sites are left to the
network.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from posecast.body.geom import BONE_M, norm3, swing_mat, turn_joint
from posecast.body.upper_ik import REACH_TOLERANCE_M, two_bone
from posecast.geometry.rotations import mat2quat, quat2mat
from posecast.skeleton import Joint
from posecast.tracking.sites import SITE_ROW, Kind, Site

F32 = NDArray[np.float32]
F64 = NDArray[np.float64]

# Per leg (left, right): thigh (hip), shin (knee), foot (ankle), and the site rows.
_LEGS = (
    (Joint.LEFT_THIGH, Joint.LEFT_SHIN, Joint.LEFT_FOOT, Site.LEFT_FOOT, Site.LEFT_KNEE),
    (Joint.RIGHT_THIGH, Joint.RIGHT_SHIN, Joint.RIGHT_FOOT, Site.RIGHT_FOOT, Site.RIGHT_KNEE),
)
_LEG_SITES = [SITE_ROW[s] for leg in _LEGS for s in leg[3:]]  # feet and knees' site rows
# Joints whose world rotation the pass may change: both legs, toes included.
LEG_JOINTS = [int(j) for j in range(Joint.LEFT_THIGH, Joint.RIGHT_TOE + 1)]


def _hinge_twist(thigh: F64, shin_dir: F64) -> F64:
    """The thigh's world rotations ``(R, 3, 3)`` twisted about its own bone so that the
    knee bends as a hinge: the shin (direction ``shin_dir (R, 3)``) in the thigh's
    sagittal plane, behind its axis. A twist about the bone moves no joint (its child
    keeps its world rotation); it fades out as the leg straightens, where the bend's
    plane is undefined."""
    n = np.linalg.norm(shin_dir, axis=-1, keepdims=True)
    lx, lz = (np.einsum("rba,rb->ra", thigh, shin_dir / np.maximum(n, 1e-9))[:, i] for i in (0, 2))
    h = np.hypot(lx, lz)
    alpha = np.arctan2(-lx, -lz) * np.clip((h - _STRAIGHT) / _BENT, 0.0, 1.0)
    c, s = np.cos(alpha), np.sin(alpha)
    twist = np.zeros((len(thigh), 3, 3))
    twist[:, 0, 0], twist[:, 0, 2], twist[:, 1, 1] = c, s, 1.0
    twist[:, 2, 0], twist[:, 2, 2] = -s, c
    out: F64 = thigh @ twist
    return out


# Knee bends (sine of the angle) below which the thigh keeps its twist, and over which
# the hinge twist fades in.
_STRAIGHT, _BENT = np.sin(np.radians(5.0)), np.sin(np.radians(15.0)) - np.sin(np.radians(5.0))


def tracks_legs(kinds: NDArray[np.integer]) -> NDArray[np.bool_]:
    """Per row of ``kinds (E, 10)``, whether the pass has anything to do."""
    out: NDArray[np.bool_] = (np.asarray(kinds)[:, _LEG_SITES] == Kind.POSITIONAL).any(axis=1)
    return out


def senses_legs(kinds: NDArray[np.integer]) -> NDArray[np.bool_]:
    """Per row of ``kinds (E, 10)``, whether the set tracks a foot or a knee in any way
    (positional or inertial): its legs then carry evidence of their own, which a
    guessed pelvis's lean (``upper_ik.lean_root``) would bend at the hips."""
    out: NDArray[np.bool_] = (np.asarray(kinds)[:, _LEG_SITES] != Kind.ABSENT).any(axis=1)
    return out


def solve_legs(
    positions: NDArray[np.floating],
    rotations: NDArray[np.floating],
    site_pos: NDArray[np.floating],
    site_quat: NDArray[np.floating],
    kinds: NDArray[np.integer],
) -> tuple[F32, F32, NDArray[np.bool_]]:
    """Feet and knees of ``E`` poses onto their positional trackers.

    Args:
        positions: world joint positions ``(E, 19, 3)`` (FK of ``rotations``), metres.
        rotations: world joint rotations ``(E, 19, 4)`` xyzw.
        site_pos: the sites ``(E, 10, 3)`` in model row order, same frame and scale
            (only positional rows are read).
        site_quat: their orientations ``(E, 10, 4)`` xyzw (calibration offsets applied).
        kinds: ``(E, 10)`` :class:`~posecast.tracking.sites.Kind` per row.

    Returns:
        ``(positions (E, 19, 3), rotations (E, 19, 4), reach_limited (E,))``, float32.
    """
    pos = np.asarray(positions, np.float64).copy()
    quat_in = np.asarray(rotations)
    mat = quat2mat(quat_in)
    sp = np.asarray(site_pos, np.float64)
    smat = quat2mat(np.asarray(site_quat, np.float64))
    k = np.asarray(kinds)
    limited = np.zeros(len(pos), np.bool_)
    for thigh, shin, foot, foot_site, knee_site in _LEGS:
        fr, kr = SITE_ROW[foot_site], SITE_ROW[knee_site]
        has_foot = k[:, fr] == Kind.POSITIONAL
        has_knee = k[:, kr] == Kind.POSITIONAL
        rows = np.flatnonzero(has_foot)
        if len(rows):
            p, m = pos[rows], mat[rows]
            pole = np.where(has_knee[rows, None], sp[rows, kr], p[:, shin])
            target = sp[rows, fr]
            knee, ankle = two_bone(
                p[:, thigh],
                pole,
                target,
                float(BONE_M[shin]),
                float(BONE_M[foot]),
                np.broadcast_to(m[:, thigh, :, 2], (len(rows), 3)),  # a straight leg bends forward
            )
            turn_joint(p, m, int(thigh), swing_mat(p[:, shin] - p[:, thigh], knee - p[:, thigh]))
            turn_joint(p, m, int(shin), swing_mat(p[:, foot] - p[:, shin], ankle - p[:, shin]))
            R = smat[rows, fr] @ np.swapaxes(m[:, foot], -1, -2)  # foot onto the tracker's
            turn_joint(p, m, int(foot), R)
            m[:, thigh] = _hinge_twist(m[:, thigh], p[:, foot] - p[:, shin])
            limited[rows] |= norm3(p[:, foot] - target) > REACH_TOLERANCE_M
            pos[rows], mat[rows] = p, m
        rows = np.flatnonzero(has_knee & ~has_foot)
        if len(rows):
            p, m = pos[rows], mat[rows]
            target = sp[rows, kr]
            turn_joint(p, m, int(thigh), swing_mat(p[:, shin] - p[:, thigh], target - p[:, thigh]))
            limited[rows] |= norm3(p[:, shin] - target) > REACH_TOLERANCE_M
            pos[rows], mat[rows] = p, m
    quats = np.array(quat_in, np.float32, copy=True)
    quats[:, LEG_JOINTS] = mat2quat(mat[:, LEG_JOINTS])
    return pos.astype(np.float32), quats, limited
