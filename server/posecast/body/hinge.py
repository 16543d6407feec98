"""Knees and elbows that bend as hinges, on the shown pose (rotations only, no joint
moves). The knees are described here; the elbows (:func:`hinge_elbows`, after the
upper-body pass) are the same code with the elbow's axis.

In the retargeted mocap a knee is a hinge: the shin's rotation relative to the thigh
turns about the thigh's local x axis (the axis of the knee's local rotations on the
validation split's ground truth spreads 0.2 degrees about it, median). The network's
knees are not quite, and the contact IK, the floor pass and the clearance swing thigh
and shin each by its own smallest rotation, which leaves a knee bent partly sideways in
its thigh's frame (the plausibility check's `joint_angle` flags, 0.8 % of val frames,
4-point `cvae_ik`), and a shin whose twist a skinned calf shows.

For each leg, from the hip, knee and ankle positions: the thigh turns about its own
bone so that the shin lies in the thigh's hinge plane, bent backward; the shin's world
rotation becomes the thigh's turned about the hinge axis by the knee's angle (its own
bone direction is kept, so the ankle stays). The foot keeps its world rotation. Near a
straight knee the plane is undefined, so the correction fades in between 5 and 15
degrees of bend (as the tracker sets' leg pass does), and a knee the network bends
backward is left as it is.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from posecast.body.geom import cross3, unit3, wrap_angle
from posecast.geometry.rotations import axis_angle_mat, mat2quat, quat2mat
from posecast.skeleton import NUM_JOINTS, Joint

F64 = NDArray[np.float64]
# Per limb: the upper, lower and end joint, the hinge axis and the flexed direction,
# both in the upper joint's frame.
Limbs = tuple[tuple[int, int, int, F64, F64], ...]

# (thigh, shin, foot) per leg; the thigh's bone along its local -y, the knee's hinge
# axis its local +x (a positive turn moves the shin backward).
KNEES = (
    (int(Joint.LEFT_THIGH), int(Joint.LEFT_SHIN), int(Joint.LEFT_FOOT)),
    (int(Joint.RIGHT_THIGH), int(Joint.RIGHT_SHIN), int(Joint.RIGHT_FOOT)),
)
_AXIS = np.array([1.0, 0.0, 0.0])
_BEHIND = np.array([0.0, 0.0, -1.0])  # where a flexed shin points, in the thigh's frame
KNEE_LIMBS: Limbs = tuple((*leg, _AXIS, _BEHIND) for leg in KNEES)

# (upper arm, forearm, hand) per arm and the elbow's hinge axis in the upper arm's frame
# (a positive turn flexes the elbow), as the validation split's ground truth has it: the
# axis of every elbow bent more than 20 degrees lies within 0.4 degrees of it (median;
# 1.2 at the 90th percentile). The upper arm's bone is its local +x (left) or -x
# (right); a flexed forearm points forward and up, the axis crossed with the bone.
ELBOWS = (
    (int(Joint.LEFT_UPPER_ARM), int(Joint.LEFT_FOREARM), int(Joint.LEFT_HAND)),
    (int(Joint.RIGHT_UPPER_ARM), int(Joint.RIGHT_FOREARM), int(Joint.RIGHT_HAND)),
)
_LEFT_AXIS, _RIGHT_AXIS = np.array([0.0, -0.868, 0.497]), np.array([0.0, 0.867, -0.499])
ELBOW_AXES = (_LEFT_AXIS / np.linalg.norm(_LEFT_AXIS), _RIGHT_AXIS / np.linalg.norm(_RIGHT_AXIS))
_BONES = (np.array([1.0, 0.0, 0.0]), np.array([-1.0, 0.0, 0.0]))  # the upper arms' own
ELBOW_LIMBS: Limbs = tuple(
    (*arm, axis, np.cross(axis, bone))
    for arm, axis, bone in zip(ELBOWS, ELBOW_AXES, _BONES, strict=True)
)
# Knee bends (sine of the angle) below which nothing changes, and the span over which
# the correction fades in.
_STRAIGHT = np.sin(np.radians(5.0))
_SPAN = np.sin(np.radians(15.0)) - _STRAIGHT
# Turns of the thigh (radians) over which the correction fades out, to none at _FLIP
# (0.05 % of bent val knees, 4-point `cvae_ik`, need more than 90 degrees; 90 % under 11).
_FLIP, _FLIP_SPAN = np.radians(90.0), np.radians(30.0)


def _twist_angle(rot: F64, axis: F64) -> F64:
    """The angle ``(B,)`` of the twist part of ``rot (B, 3, 3)`` about unit ``axis``:
    ``2 atan2(axis . v, w)`` of its quaternion, from the matrix directly (``v`` and
    ``w`` scaled alike by ``4 w``: the antisymmetric part and ``1 + trace``)."""
    v = np.stack(
        [rot[:, 2, 1] - rot[:, 1, 2], rot[:, 0, 2] - rot[:, 2, 0], rot[:, 1, 0] - rot[:, 0, 1]],
        axis=-1,
    )
    w = 1.0 + rot[:, 0, 0] + rot[:, 1, 1] + rot[:, 2, 2]
    return wrap_angle(2.0 * np.arctan2(np.einsum("bi,bi->b", v, axis), w))


def hinge_knees(mat: F64, pos: F64) -> None:
    """Both knees of ``B`` poses onto their hinges, in place: world rotations
    ``mat (B, 19, 3, 3)`` change, positions ``pos (B, 19, 3)`` are read only."""
    _hinge(mat, pos, KNEE_LIMBS)


def hinge_elbows(mat: F64, pos: F64) -> None:
    """Both elbows of ``B`` poses onto their hinges, as :func:`hinge_knees` the knees:
    each upper arm turns about its bone so that the forearm lies in its hinge plane,
    the forearm's rotation becomes the upper arm's turned about the hinge axis, and the
    hand keeps its world rotation (the controller's)."""
    _hinge(mat, pos, ELBOW_LIMBS)


def _hinge(mat: F64, pos: F64, limbs: Limbs) -> None:
    """Every limb of ``limbs`` (upper, lower, end joint, the hinge axis and the flexed
    direction in the upper joint's frame) onto its hinge, all limbs in one batch."""
    B, L = len(pos), len(limbs)
    upper = [limb[0] for limb in limbs]
    lower = [limb[1] for limb in limbs]
    end = [limb[2] for limb in limbs]
    axis = np.tile(np.stack([limb[3] for limb in limbs]), (B, 1))  # (B L, 3)
    behind_local = np.tile(np.stack([limb[4] for limb in limbs]), (B, 1))
    a, _ = unit3((pos[:, lower] - pos[:, upper]).reshape(-1, 3))  # the upper bones
    f, _ = unit3((pos[:, end] - pos[:, lower]).reshape(-1, 3))  # the lower ones
    cos = np.clip(np.einsum("bi,bi->b", a, f), -1.0, 1.0)
    bend, _ = unit3(f - cos[:, None] * a)  # where the lower bone leaves the upper's line
    weight = np.clip((np.sqrt(1.0 - cos**2) - _STRAIGHT) / _SPAN, 0.0, 1.0)
    Rt = mat[:, upper].reshape(-1, 3, 3)
    behind = np.einsum("bij,bj->bi", Rt, behind_local)
    behind, _ = unit3(behind - np.einsum("bi,bi->b", behind, a)[:, None] * a)
    alpha = np.arctan2(
        np.einsum("bi,bi->b", cross3(behind, bend), a), np.einsum("bi,bi->b", behind, bend)
    )
    # A limb bent the wrong way (a knee or an elbow bent backward) would need its upper
    # bone turned half round: such limbs fade back to the network's.
    weight = weight * np.clip((_FLIP - np.abs(alpha)) / _FLIP_SPAN, 0.0, 1.0)
    Rt = axis_angle_mat(a, alpha * weight) @ Rt
    Rs = mat[:, lower].reshape(-1, 3, 3)
    hinged = Rt @ axis_angle_mat(axis, np.arccos(cos))
    beta = _twist_angle(hinged @ np.swapaxes(Rs, -1, -2), f)
    mat[:, upper] = Rt.reshape(B, L, 3, 3)
    mat[:, lower] = (axis_angle_mat(f, beta * weight) @ Rs).reshape(B, L, 3, 3)


def hinge_quat(
    positions: NDArray[np.floating], rotations: NDArray[np.floating], limbs: Limbs
) -> None:
    """The limbs ``limbs`` (:data:`KNEE_LIMBS` or :data:`ELBOW_LIMBS`) of the engine's
    shown poses onto their hinges: world rotations ``(E, 19, 4)`` xyzw (float32,
    changed in place on each limb's upper and lower joint) and positions, read only.
    The reference the backends' ``Pool.hinge`` runs (``native``: in C, which turns
    limb by limb and so refuses tables whose limbs share a joint)."""
    joints = sorted({j for limb in limbs for j in limb[:2]})
    mat = quat2mat(np.asarray(rotations[:, joints], np.float64))
    full = np.zeros((len(mat), NUM_JOINTS, 3, 3))
    full[:, joints] = mat
    _hinge(full, np.asarray(positions, np.float64), limbs)
    rotations[:, joints] = mat2quat(full[:, joints])


def limb_table(limbs: Limbs) -> F64:
    """``limbs`` as one ``(L, 9)`` float64 table (the three joints, the axis, the flexed
    direction): what the C port reads, with :data:`FADES`."""
    table = np.array([[u, lo, e, *axis, *behind] for u, lo, e, axis, behind in limbs], np.float64)
    return table


# The fades' constants, for the C port: straight, span, flip, flip span.
FADES = (float(_STRAIGHT), float(_SPAN), float(_FLIP), float(_FLIP_SPAN))


def hinge_knees_quat(positions: NDArray[np.floating], rotations: NDArray[np.floating]) -> None:
    """:func:`hinge_knees` on the engine's shown poses: world rotations ``(E, 19, 4)``
    xyzw (float32, changed in place on the thighs and shins) and positions."""
    hinge_quat(positions, rotations, KNEE_LIMBS)


def hinge_elbows_quat(positions: NDArray[np.floating], rotations: NDArray[np.floating]) -> None:
    """:func:`hinge_elbows` on the engine's shown poses (upper arms and forearms change)."""
    hinge_quat(positions, rotations, ELBOW_LIMBS)
