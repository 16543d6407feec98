"""Knees that bend as hinges, on the shown pose (rotations only, no joint moves).

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

from posecast.geometry.rotations import aa2mat, mat2quat, quat2mat
from posecast.online.engine.ik import cross3, unit3
from posecast.online.engine.upper_ik import _wrap
from posecast.skeleton import Joint

F64 = NDArray[np.float64]

# (thigh, shin, foot) per leg; the thigh's bone along its local -y, the knee's hinge
# axis its local +x (a positive turn moves the shin backward).
KNEES = (
    (int(Joint.LEFT_THIGH), int(Joint.LEFT_SHIN), int(Joint.LEFT_FOOT)),
    (int(Joint.RIGHT_THIGH), int(Joint.RIGHT_SHIN), int(Joint.RIGHT_FOOT)),
)
HINGE_JOINTS = [j for leg in KNEES for j in leg[:2]]
_AXIS = np.array([1.0, 0.0, 0.0])
_BEHIND = np.array([0.0, 0.0, -1.0])  # where a flexed shin points, in the thigh's frame
# Knee bends (sine of the angle) below which nothing changes, and the span over which
# the correction fades in.
_STRAIGHT = np.sin(np.radians(5.0))
_SPAN = np.sin(np.radians(15.0)) - _STRAIGHT
# Turns of the thigh (radians) over which the correction fades out, to none at _FLIP
# (0.05 % of bent val knees, 4-point `cvae_ik`, need more than 90 degrees; 90 % under 11).
_FLIP, _FLIP_SPAN = np.radians(90.0), np.radians(30.0)


def _twist_angle(rot: F64, axis: F64) -> F64:
    """The angle ``(B,)`` of the twist part of ``rot (B, 3, 3)`` about unit ``axis``."""
    q = mat2quat(rot)
    return _wrap(2.0 * np.arctan2(np.einsum("bi,bi->b", q[:, :3], axis), q[:, 3]))


def hinge_knees(mat: F64, pos: F64) -> None:
    """Both knees of ``B`` poses onto their hinges, in place: world rotations
    ``mat (B, 19, 3, 3)`` change, positions ``pos (B, 19, 3)`` are read only."""
    for thigh, shin, foot in KNEES:
        a, _ = unit3(pos[:, shin] - pos[:, thigh])  # the thigh's bone
        f, _ = unit3(pos[:, foot] - pos[:, shin])  # the shin's
        cos = np.clip(np.einsum("bi,bi->b", a, f), -1.0, 1.0)
        bend, _ = unit3(f - cos[:, None] * a)  # where the shin leaves the thigh's line
        weight = np.clip((np.sqrt(1.0 - cos**2) - _STRAIGHT) / _SPAN, 0.0, 1.0)
        Rt = mat[:, thigh]
        behind = np.einsum("bij,j->bi", Rt, _BEHIND)
        behind, _ = unit3(behind - np.einsum("bi,bi->b", behind, a)[:, None] * a)
        alpha = np.arctan2(
            np.einsum("bi,bi->b", cross3(behind, bend), a), np.einsum("bi,bi->b", behind, bend)
        )
        # A shin in front of its thigh (a knee bent backward) would need the thigh
        # turned half round: such knees fade back to the network's.
        weight = weight * np.clip((_FLIP - np.abs(alpha)) / _FLIP_SPAN, 0.0, 1.0)
        Rt = aa2mat(a * (alpha * weight)[:, None]) @ Rt
        Rs = mat[:, shin]
        hinged = Rt @ aa2mat(_AXIS * np.arccos(cos)[:, None])
        beta = _twist_angle(hinged @ np.swapaxes(Rs, -1, -2), f)
        mat[:, thigh], mat[:, shin] = Rt, aa2mat(f * (beta * weight)[:, None]) @ Rs


def hinge_knees_quat(positions: NDArray[np.floating], rotations: NDArray[np.floating]) -> None:
    """:func:`hinge_knees` on the engine's shown poses: world rotations ``(E, 19, 4)``
    xyzw (float32, changed in place on the thighs and shins) and positions."""
    mat = quat2mat(np.asarray(rotations[:, HINGE_JOINTS], np.float64))
    full = np.zeros((len(mat), int(Joint.RIGHT_TOE) + 1, 3, 3))
    full[:, HINGE_JOINTS] = mat
    hinge_knees(full, np.asarray(positions, np.float64))
    rotations[:, HINGE_JOINTS] = mat2quat(full[:, HINGE_JOINTS])
