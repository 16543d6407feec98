"""Engine conventions: a posecast pose in Unity's, Unreal's and three.js's frames, and
posecast's 19 joints by their Unity, VRM and Unreal mannequin bone names.

posecast's world (``proto/README.md``, Conventions) is right-handed, +Y up, metres;
a character faces +Z and its left is +X; quaternions are xyzw. Each engine's frame is
a change of basis ``p_engine = scale * BASIS @ p_posecast`` that keeps up, forward and
the character's right where the engine expects them (``docs/game-engines.md``):

=======  =============  ==============  ==================  ======================
engine   handedness     up, forward     position            quaternion xyzw
=======  =============  ==============  ==================  ======================
unity    left           +Y, +Z          ``(-x, y, z)``      ``(x, -y, -z, w)``
unreal   left           +Z, +X          ``100 (z, -x, y)``  ``(-z, x, -y, w)``
three    right (same)   +Y, +Z          unchanged           unchanged
=======  =============  ==============  ==================  ======================

A basis with determinant -1 (a mirror, Unity's and Unreal's) turns a rotation's axis
into ``-BASIS @ axis`` and keeps its angle's cosine, hence the quaternion column
(``R_engine = BASIS @ R @ BASIS.T``). three.js, WebXR reference spaces and glTF share
posecast's frame; only a WebXR *viewer* (a camera) looks down -Z where a posecast head
faces +Z: :func:`head2xrview_quat` turns one into the other.

A pose's rotation of joint ``j`` is the turn from the T-pose rest (every rotation
identity, facing +Z) to now, in the world. An engine bone with its own rest rotation
``rest_j`` (its world rotation with the avatar in a T-pose facing the engine's
forward) takes ``quat2engine(q_j) * rest_j``.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from enum import StrEnum
from types import MappingProxyType

import numpy as np
from numpy.typing import ArrayLike, NDArray

from posecast_client.skeleton import Joint

F64 = NDArray[np.float64]


class Engine(StrEnum):
    UNITY = "unity"  # left-handed, +Y up, +Z forward, +X right, metres
    UNREAL = "unreal"  # left-handed, +Z up, +X forward, +Y right, centimetres
    THREE = "three"  # three.js, WebXR reference spaces, glTF: posecast's own frame


@dataclass(frozen=True)
class EngineFrame:
    """One engine's world: ``p_engine = scale * basis @ p_posecast``."""

    engine: Engine
    basis: tuple[tuple[float, float, float], ...]  # 3x3, rows: engine axes in posecast
    scale: float  # engine length units per metre
    right_handed: bool

    @property
    def matrix(self) -> F64:
        return np.array(self.basis, dtype=np.float64)


FRAMES: Mapping[Engine, EngineFrame] = MappingProxyType(
    {
        # Unity: posecast's character right (-X) becomes +X; up and forward stay.
        Engine.UNITY: EngineFrame(Engine.UNITY, ((-1, 0, 0), (0, 1, 0), (0, 0, 1)), 1.0, False),
        # Unreal: X forward (posecast +Z), Y right (posecast -X), Z up (posecast +Y).
        Engine.UNREAL: EngineFrame(Engine.UNREAL, ((0, 0, 1), (-1, 0, 0), (0, 1, 0)), 100.0, False),
        Engine.THREE: EngineFrame(Engine.THREE, ((1, 0, 0), (0, 1, 0), (0, 0, 1)), 1.0, True),
    }
)


def pos2engine(p: ArrayLike, engine: Engine | str) -> F64:
    """posecast positions ``(..., 3)`` metres -> the engine's frame and units."""
    f = FRAMES[Engine(engine)]
    out: F64 = f.scale * (np.asarray(p, dtype=np.float64) @ f.matrix.T)
    return out


def engine2pos(p: ArrayLike, engine: Engine | str) -> F64:
    """Engine positions ``(..., 3)`` -> posecast metres (the inverse of :func:`pos2engine`)."""
    f = FRAMES[Engine(engine)]
    out: F64 = (np.asarray(p, dtype=np.float64) @ f.matrix) / f.scale
    return out


def quat2engine(q: ArrayLike, engine: Engine | str) -> F64:
    """posecast rotations ``(..., 4)`` xyzw -> the engine's xyzw (``Quaternion``,
    ``FQuat``, ``THREE.Quaternion`` all store x, y, z, w)."""
    f = FRAMES[Engine(engine)]
    a = np.asarray(q, dtype=np.float64)
    det = 1.0 if f.right_handed else -1.0  # the basis's determinant
    vec = det * (a[..., :3] @ f.matrix.T)  # the axis, an axial vector
    return np.concatenate([vec, a[..., 3:]], axis=-1)


def engine2quat(q: ArrayLike, engine: Engine | str) -> F64:
    """Engine rotations ``(..., 4)`` xyzw -> posecast xyzw (the inverse of
    :func:`quat2engine`), e.g. tracker orientations read from an engine's XR API."""
    f = FRAMES[Engine(engine)]
    a = np.asarray(q, dtype=np.float64)
    det = 1.0 if f.right_handed else -1.0
    vec = det * (a[..., :3] @ f.matrix)
    return np.concatenate([vec, a[..., 3:]], axis=-1)


def head2xrview_quat(q: ArrayLike) -> F64:
    """A posecast head (or tracker) rotation ``(..., 4)`` -> the orientation of a WebXR
    viewer or three.js camera at it: turned 180 degrees about its own Y, since a camera
    looks down its -Z and a posecast head faces +Z (``q * (0, 1, 0, 0)``). The same map
    takes a WebXR pose to posecast (the SDKs' ``xrToPosecast``): it is its own inverse
    up to the sign of ``q``."""
    x, y, z, w = np.moveaxis(np.asarray(q, dtype=np.float64), -1, 0)
    return np.stack([-z, w, x, -y], axis=-1)


@dataclass(frozen=True)
class EnginePose:
    positions: F64  # (J, 3) engine units
    rotations: F64 | None  # (J, 4) engine xyzw


def pose2engine(
    positions: ArrayLike, rotations: ArrayLike | None, engine: Engine | str
) -> EnginePose:
    """A pose's world positions ``(J, 3)`` and rotations ``(J, 4)`` (or ``None``) in an
    engine's frame: a :class:`~posecast_client.protocol.Pose` or an
    :class:`~posecast_client.interp.InterpolatedPose`'s arrays."""
    rot = None if rotations is None else quat2engine(rotations, engine)
    return EnginePose(pos2engine(positions, engine), rot)


# Bone names: every posecast joint has a bone of each rig. The rigs' extra bones
# (shoulders/clavicles, upper chest, UE5's spine_02/04/05 and neck_02) have no posecast
# joint: leave them at their rest pose. Unreal: SK_Mannequin (UE4) and Manny/Quinn
# (UE5) name the same bones except the chest, spine_03 in UE4 and spine_05 (the
# clavicles' parent) in UE5.
BONE_RIGS = ("unity", "vrm", "unreal", "unreal_ue4")

_BONES: dict[Joint, tuple[str, str, str, str]] = {
    # joint: (Unity HumanBodyBones, VRM humanoid, UE5 Manny, UE4 Mannequin)
    Joint.PELVIS: ("Hips", "hips", "pelvis", "pelvis"),
    Joint.SPINE: ("Spine", "spine", "spine_01", "spine_01"),
    Joint.CHEST: ("Chest", "chest", "spine_05", "spine_03"),
    Joint.NECK: ("Neck", "neck", "neck_01", "neck_01"),
    Joint.HEAD: ("Head", "head", "head", "head"),
    Joint.LEFT_UPPER_ARM: ("LeftUpperArm", "leftUpperArm", "upperarm_l", "upperarm_l"),
    Joint.LEFT_FOREARM: ("LeftLowerArm", "leftLowerArm", "lowerarm_l", "lowerarm_l"),
    Joint.LEFT_HAND: ("LeftHand", "leftHand", "hand_l", "hand_l"),
    Joint.RIGHT_UPPER_ARM: ("RightUpperArm", "rightUpperArm", "upperarm_r", "upperarm_r"),
    Joint.RIGHT_FOREARM: ("RightLowerArm", "rightLowerArm", "lowerarm_r", "lowerarm_r"),
    Joint.RIGHT_HAND: ("RightHand", "rightHand", "hand_r", "hand_r"),
    Joint.LEFT_THIGH: ("LeftUpperLeg", "leftUpperLeg", "thigh_l", "thigh_l"),
    Joint.LEFT_SHIN: ("LeftLowerLeg", "leftLowerLeg", "calf_l", "calf_l"),
    Joint.LEFT_FOOT: ("LeftFoot", "leftFoot", "foot_l", "foot_l"),
    Joint.LEFT_TOE: ("LeftToes", "leftToes", "ball_l", "ball_l"),
    Joint.RIGHT_THIGH: ("RightUpperLeg", "rightUpperLeg", "thigh_r", "thigh_r"),
    Joint.RIGHT_SHIN: ("RightLowerLeg", "rightLowerLeg", "calf_r", "calf_r"),
    Joint.RIGHT_FOOT: ("RightFoot", "rightFoot", "foot_r", "foot_r"),
    Joint.RIGHT_TOE: ("RightToes", "rightToes", "ball_r", "ball_r"),
}

BONES: Mapping[str, Mapping[Joint, str]] = MappingProxyType(
    {
        rig: MappingProxyType({j: names[k] for j, names in _BONES.items()})
        for k, rig in enumerate(BONE_RIGS)
    }
)
