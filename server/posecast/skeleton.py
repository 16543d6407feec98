"""The canonical 19-joint posecast skeleton.

Conventions (stated once, used everywhere):

* Right-handed world, **+Y up**, metres.
* The character faces **+Z** in its rest pose; its left side is **+X**.
* Rest pose (all local rotations identity) is a T-pose: arms along ±X, palms down,
  legs down. So a joint's world rotation maps its own axes onto the world's as the
  body stands in the rest pose: +X the body's left, +Y up, +Z forward.
* Quaternions are **xyzw** (scalar last).
* Joint ``j``'s world position is ``p[parent] + R_world[parent] @ offset[j]``; the
  root (``PELVIS``) takes its world position and rotation from the waist tracker.

There are 19 joints and therefore 18 non-root local rotations: the network predicts
those 18 (as 6D), the root rotation comes from the waist tracker. Leaf joints
(``HEAD``, hands, toes) carry a rotation too: it moves no other joint, but gives the
head and hand orientation (the tracker orientation) and is written to BVH.

The reference body is about 1.75 m tall: head joint at 1.60 m, the top of the head
some 15 cm above it. ``docs/skeleton.md`` has the table and a picture in words.
"""

from __future__ import annotations

from enum import IntEnum

import numpy as np
from numpy.typing import NDArray


class Joint(IntEnum):
    """The 19 canonical joints, in topological order (parents before children)."""

    PELVIS = 0
    SPINE = 1
    CHEST = 2
    NECK = 3
    HEAD = 4
    LEFT_UPPER_ARM = 5
    LEFT_FOREARM = 6
    LEFT_HAND = 7
    RIGHT_UPPER_ARM = 8
    RIGHT_FOREARM = 9
    RIGHT_HAND = 10
    LEFT_THIGH = 11
    LEFT_SHIN = 12
    LEFT_FOOT = 13
    LEFT_TOE = 14
    RIGHT_THIGH = 15
    RIGHT_SHIN = 16
    RIGHT_FOOT = 17
    RIGHT_TOE = 18


NUM_JOINTS = len(Joint)
NUM_ROTATIONS = NUM_JOINTS - 1  # the 18 non-root joints the network predicts
JOINT_NAMES: tuple[str, ...] = tuple(j.name for j in Joint)

PARENT: dict[Joint, Joint | None] = {
    Joint.PELVIS: None,
    Joint.SPINE: Joint.PELVIS,
    Joint.CHEST: Joint.SPINE,
    Joint.NECK: Joint.CHEST,
    Joint.HEAD: Joint.NECK,
    Joint.LEFT_UPPER_ARM: Joint.CHEST,
    Joint.LEFT_FOREARM: Joint.LEFT_UPPER_ARM,
    Joint.LEFT_HAND: Joint.LEFT_FOREARM,
    Joint.RIGHT_UPPER_ARM: Joint.CHEST,
    Joint.RIGHT_FOREARM: Joint.RIGHT_UPPER_ARM,
    Joint.RIGHT_HAND: Joint.RIGHT_FOREARM,
    Joint.LEFT_THIGH: Joint.PELVIS,
    Joint.LEFT_SHIN: Joint.LEFT_THIGH,
    Joint.LEFT_FOOT: Joint.LEFT_SHIN,
    Joint.LEFT_TOE: Joint.LEFT_FOOT,
    Joint.RIGHT_THIGH: Joint.PELVIS,
    Joint.RIGHT_SHIN: Joint.RIGHT_THIGH,
    Joint.RIGHT_FOOT: Joint.RIGHT_SHIN,
    Joint.RIGHT_TOE: Joint.RIGHT_FOOT,
}

# Parent index per joint, -1 for the root: the array form FK loops over.
PARENTS: tuple[int, ...] = tuple(-1 if p is None else int(p) for p in PARENT.values())

# Offsets from the parent joint in the rest pose, metres (+X is the character's left).
_REFERENCE_OFFSETS_M: dict[Joint, tuple[float, float, float]] = {
    Joint.PELVIS: (0.0, 0.0, 0.0),
    Joint.SPINE: (0.0, 0.10, 0.0),
    Joint.CHEST: (0.0, 0.20, 0.0),
    Joint.NECK: (0.0, 0.22, 0.0),
    Joint.HEAD: (0.0, 0.10, 0.0),
    Joint.LEFT_UPPER_ARM: (0.17, 0.17, 0.0),
    Joint.LEFT_FOREARM: (0.28, 0.0, 0.0),
    Joint.LEFT_HAND: (0.25, 0.0, 0.0),
    Joint.RIGHT_UPPER_ARM: (-0.17, 0.17, 0.0),
    Joint.RIGHT_FOREARM: (-0.28, 0.0, 0.0),
    Joint.RIGHT_HAND: (-0.25, 0.0, 0.0),
    Joint.LEFT_THIGH: (0.09, -0.05, 0.0),
    Joint.LEFT_SHIN: (0.0, -0.43, 0.0),
    Joint.LEFT_FOOT: (0.0, -0.42, 0.0),
    Joint.LEFT_TOE: (0.0, -0.06, 0.13),
    Joint.RIGHT_THIGH: (-0.09, -0.05, 0.0),
    Joint.RIGHT_SHIN: (0.0, -0.43, 0.0),
    Joint.RIGHT_FOOT: (0.0, -0.42, 0.0),
    Joint.RIGHT_TOE: (0.0, -0.06, 0.13),
}

# Where each joint sits on a body (proto/skeleton.md's tables say it to implementers).
LANDMARK: dict[Joint, str] = {
    Joint.PELVIS: "the middle of the pelvis, between the hips (the waist tracker)",
    Joint.SPINE: "the lower back, 10 cm above the pelvis",
    Joint.CHEST: "the middle of the chest",
    Joint.NECK: "the base of the neck",
    Joint.HEAD: "the headset: the point between the eyes, no eye offset",
    Joint.LEFT_UPPER_ARM: "the left shoulder",
    Joint.LEFT_FOREARM: "the left elbow",
    Joint.LEFT_HAND: "the left wrist (a controller's grip sits a few cm off it)",
    Joint.RIGHT_UPPER_ARM: "the right shoulder",
    Joint.RIGHT_FOREARM: "the right elbow",
    Joint.RIGHT_HAND: "the right wrist (a controller's grip sits a few cm off it)",
    Joint.LEFT_THIGH: "the left hip",
    Joint.LEFT_SHIN: "the left knee",
    Joint.LEFT_FOOT: "the left ankle",
    Joint.LEFT_TOE: "the ball of the left foot",
    Joint.RIGHT_THIGH: "the right hip",
    Joint.RIGHT_SHIN: "the right knee",
    Joint.RIGHT_FOOT: "the right ankle",
    Joint.RIGHT_TOE: "the ball of the right foot",
}

# Height of the pelvis above the floor in the rest pose, and of the toe joint.
REST_PELVIS_HEIGHT_M = 0.98
REST_TOE_HEIGHT_M = 0.02

# Left/right pairs, used by mirroring.
MIRROR: dict[Joint, Joint] = {}
for _j in Joint:
    if _j.name.startswith("LEFT_"):
        MIRROR[_j] = Joint["RIGHT_" + _j.name[5:]]
    elif _j.name.startswith("RIGHT_"):
        MIRROR[_j] = Joint["LEFT_" + _j.name[6:]]
    else:
        MIRROR[_j] = _j
MIRROR_INDEX: tuple[int, ...] = tuple(int(MIRROR[j]) for j in Joint)

LOWER_BODY: tuple[Joint, ...] = (
    Joint.LEFT_THIGH,
    Joint.LEFT_SHIN,
    Joint.LEFT_FOOT,
    Joint.LEFT_TOE,
    Joint.RIGHT_THIGH,
    Joint.RIGHT_SHIN,
    Joint.RIGHT_FOOT,
    Joint.RIGHT_TOE,
)
FEET: tuple[Joint, Joint] = (Joint.LEFT_FOOT, Joint.RIGHT_FOOT)
TOES: tuple[Joint, Joint] = (Joint.LEFT_TOE, Joint.RIGHT_TOE)


def reference_offsets() -> NDArray[np.float64]:
    """Rest-pose offsets of the reference body, ``(19, 3)`` metres (a fresh copy)."""
    return np.array([_REFERENCE_OFFSETS_M[j] for j in Joint], dtype=np.float64)


def children(joint: Joint) -> tuple[Joint, ...]:
    """Direct children of ``joint`` in topological order."""
    return tuple(j for j in Joint if PARENT[j] == joint)
