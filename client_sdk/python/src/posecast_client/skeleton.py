"""The canonical 19-joint skeleton and the four tracker slots, as the wire uses them.

World: right-handed, +Y up, metres; a character faces +Z in its rest pose and its
left side is +X. The rest pose (every local rotation identity) is a T-pose. Joint
``j``'s world position is ``p[parent] + R_world[parent] @ OFFSETS_M[j]``.

These tables mirror ``server/posecast/skeleton.py`` and ``tracking/features.py`` (a test
compares them when the server package is installed).
"""

from __future__ import annotations

from enum import IntEnum

import numpy as np
from numpy.typing import NDArray


class Joint(IntEnum):
    """The 19 canonical joints in wire order (parents before children)."""

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


class TrackerSlot(IntEnum):
    """The four tracked points of a ``frame``, in wire order."""

    HEAD = 0
    LEFT_HAND = 1
    RIGHT_HAND = 2
    WAIST = 3


NUM_JOINTS = len(Joint)
NUM_TRACKERS = len(TrackerSlot)
JOINT_NAMES: tuple[str, ...] = tuple(j.name for j in Joint)

# Parent of each joint, -1 for the root.
PARENTS: tuple[int, ...] = (-1, 0, 1, 2, 3, 2, 5, 6, 2, 8, 9, 0, 11, 12, 13, 0, 15, 16, 17)

# Rest offsets from the parent of the reference body (about 1.75 m tall), metres.
_OFFSETS_M = (
    (0.0, 0.0, 0.0),  # PELVIS
    (0.0, 0.10, 0.0),  # SPINE
    (0.0, 0.20, 0.0),  # CHEST
    (0.0, 0.22, 0.0),  # NECK
    (0.0, 0.10, 0.0),  # HEAD
    (0.17, 0.17, 0.0),  # LEFT_UPPER_ARM
    (0.28, 0.0, 0.0),  # LEFT_FOREARM
    (0.25, 0.0, 0.0),  # LEFT_HAND
    (-0.17, 0.17, 0.0),  # RIGHT_UPPER_ARM
    (-0.28, 0.0, 0.0),  # RIGHT_FOREARM
    (-0.25, 0.0, 0.0),  # RIGHT_HAND
    (0.09, -0.05, 0.0),  # LEFT_THIGH
    (0.0, -0.43, 0.0),  # LEFT_SHIN
    (0.0, -0.42, 0.0),  # LEFT_FOOT
    (0.0, -0.06, 0.13),  # LEFT_TOE
    (-0.09, -0.05, 0.0),  # RIGHT_THIGH
    (0.0, -0.43, 0.0),  # RIGHT_SHIN
    (0.0, -0.42, 0.0),  # RIGHT_FOOT
    (0.0, -0.06, 0.13),  # RIGHT_TOE
)
REST_PELVIS_HEIGHT_M = 0.98  # pelvis above the floor in the rest pose

# The joint each tracker slot sits on.
TRACKER_JOINTS: tuple[Joint, ...] = (Joint.HEAD, Joint.LEFT_HAND, Joint.RIGHT_HAND, Joint.PELVIS)


def reference_offsets() -> NDArray[np.float64]:
    """Rest offsets of the reference body, ``(19, 3)`` metres (a fresh copy)."""
    return np.array(_OFFSETS_M, dtype=np.float64)


def children(joint: int) -> tuple[int, ...]:
    """Direct children of ``joint``, in joint order."""
    return tuple(j for j, p in enumerate(PARENTS) if p == joint)
