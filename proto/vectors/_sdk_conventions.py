"""``proto/vectors/sdk/conventions.json``: each engine's frame as up/forward/right axes
and a unit, poses converted by the rotation-matrix route ``R' = M R M^T`` (the SDKs
flip quaternion components), the WebXR view turn, and the joint -> bone-name table,
which is defined here and copied by both SDKs (``docs/game-engines.md``).
"""

from __future__ import annotations

from typing import Any

import numpy as np
from _sdk_common import F64, J, unit

from posecast.geometry.rotations import aa2quat, mat2quat, quat2mat, quat_mul

# posecast's character axes: forward +Z, up +Y, right -X (its left is +X).
FORWARD, UP, RIGHT = np.array([0.0, 0, 1]), np.array([0.0, 1, 0]), np.array([-1.0, 0, 0])
# Where each engine puts them, in its own coordinates, and its length unit per metre.
ENGINES: dict[str, dict[str, Any]] = {
    "unity": {"forward": [0, 0, 1], "up": [0, 1, 0], "right": [1, 0, 0], "scale": 1.0,
              "right_handed": False, "note": "left-handed, +Y up, +Z forward, metres"},
    "unreal": {"forward": [1, 0, 0], "up": [0, 0, 1], "right": [0, 1, 0], "scale": 100.0,
               "right_handed": False, "note": "left-handed, +Z up, +X forward, centimetres"},
    "three": {"forward": [0, 0, 1], "up": [0, 1, 0], "right": [-1, 0, 0], "scale": 1.0,
              "right_handed": True, "note": "three.js / WebXR / glTF: posecast's own frame"},
}  # fmt: skip

# joint: Unity HumanBodyBones, VRM humanoid, UE5 Manny/Quinn, UE4 SK_Mannequin.
BONES = {
    "PELVIS": ("Hips", "hips", "pelvis", "pelvis"),
    "SPINE": ("Spine", "spine", "spine_01", "spine_01"),
    "CHEST": ("Chest", "chest", "spine_05", "spine_03"),
    "NECK": ("Neck", "neck", "neck_01", "neck_01"),
    "HEAD": ("Head", "head", "head", "head"),
    "LEFT_UPPER_ARM": ("LeftUpperArm", "leftUpperArm", "upperarm_l", "upperarm_l"),
    "LEFT_FOREARM": ("LeftLowerArm", "leftLowerArm", "lowerarm_l", "lowerarm_l"),
    "LEFT_HAND": ("LeftHand", "leftHand", "hand_l", "hand_l"),
    "RIGHT_UPPER_ARM": ("RightUpperArm", "rightUpperArm", "upperarm_r", "upperarm_r"),
    "RIGHT_FOREARM": ("RightLowerArm", "rightLowerArm", "lowerarm_r", "lowerarm_r"),
    "RIGHT_HAND": ("RightHand", "rightHand", "hand_r", "hand_r"),
    "LEFT_THIGH": ("LeftUpperLeg", "leftUpperLeg", "thigh_l", "thigh_l"),
    "LEFT_SHIN": ("LeftLowerLeg", "leftLowerLeg", "calf_l", "calf_l"),
    "LEFT_FOOT": ("LeftFoot", "leftFoot", "foot_l", "foot_l"),
    "LEFT_TOE": ("LeftToes", "leftToes", "ball_l", "ball_l"),
    "RIGHT_THIGH": ("RightUpperLeg", "rightUpperLeg", "thigh_r", "thigh_r"),
    "RIGHT_SHIN": ("RightLowerLeg", "rightLowerLeg", "calf_r", "calf_r"),
    "RIGHT_FOOT": ("RightFoot", "rightFoot", "foot_r", "foot_r"),
    "RIGHT_TOE": ("RightToes", "rightToes", "ball_r", "ball_r"),
}
RIGS = ("unity", "vrm", "unreal", "unreal_ue4")


def basis(engine: str) -> F64:
    """``M`` with ``p_engine = M @ p_posecast`` (before the unit): it sends posecast's
    forward, up and right onto the engine's."""
    e = ENGINES[engine]
    src = np.stack([FORWARD, UP, RIGHT], axis=1)  # columns: posecast axes
    dst = np.array([e["forward"], e["up"], e["right"]], dtype=np.float64).T
    m: F64 = dst @ np.linalg.inv(src)
    return m


def convert(engine: str, pos: F64, rot: F64) -> tuple[F64, F64]:
    m = basis(engine)
    assert np.isclose(np.linalg.det(m), 1.0 if ENGINES[engine]["right_handed"] else -1.0)
    new_pos = ENGINES[engine]["scale"] * pos @ m.T
    new_rot = mat2quat(m @ quat2mat(rot) @ m.T)  # (..., 3, 3): the same turn, seen there
    return new_pos, new_rot


def conventions() -> dict[str, Any]:
    rng = np.random.default_rng(15)
    yaw_left = aa2quat([0.0, np.pi / 2, 0.0])  # the character turns to its left
    named = {
        "forward_1m": ([0.0, 0.0, 1.0], [0.0, 0.0, 0.0, 1.0]),
        "left_1m": ([1.0, 0.0, 0.0], [0.0, 0.0, 0.0, 1.0]),
        "up_1m": ([0.0, 1.0, 0.0], [0.0, 0.0, 0.0, 1.0]),
        "turn_left_90": ([0.0, 0.0, 0.0], yaw_left.tolist()),
        "raise_left_arm_45": ([0.17, 1.45, 0.0], aa2quat([0.0, 0.0, np.pi / 4]).tolist()),
    }
    cases = []
    for engine in ENGINES:
        # What a turn to the left means there: engine forward ends on engine -right.
        _, r = convert(engine, np.zeros(3), yaw_left)
        fwd_after = quat2mat(r) @ np.array(ENGINES[engine]["forward"], dtype=np.float64)
        assert np.allclose(fwd_after, -np.array(ENGINES[engine]["right"])), engine
        for name, (p, rot) in named.items():
            pos2, rot2 = convert(engine, np.array([p]), np.array([rot]))
            cases.append({
                "name": f"{engine}_{name}", "engine": engine,
                "positions": [p], "rotations": [rot],
                "expect_positions": pos2.tolist(), "expect_rotations": rot2.tolist(),
            })  # fmt: skip
        pos = np.round(rng.uniform(-2, 2, size=(J, 3)), 6)
        rot = unit(rng.normal(size=(J, 4)))
        pos2, rot2 = convert(engine, pos, rot)
        cases.append({
            "name": f"{engine}_random_pose", "engine": engine,
            "positions": pos.tolist(), "rotations": rot.tolist(),
            "expect_positions": pos2.tolist(), "expect_rotations": rot2.tolist(),
        })  # fmt: skip
    heads = unit(rng.normal(size=(4, 4)))
    views = [[0.0, 0.0, 0.0, 1.0], *heads.tolist()]
    xr = [quat_mul(np.array(v), [0.0, 1.0, 0.0, 0.0]).tolist() for v in views]
    # A camera at the head: its -Z (where it looks) is the head's +Z (where it faces).
    for v, c in zip(views, xr, strict=True):
        assert np.allclose(quat2mat(c) @ [0, 0, -1.0], quat2mat(v) @ [0, 0, 1.0])
    return {
        "description": "posecast poses in engine frames (docs/game-engines.md); compare "
        "positions within tolerance.position_m (engine units) and rotations up to sign",
        "tolerance": {"position": 1e-9, "rotation": 1e-9},
        "engines": {k: {**v, "basis": basis(k).round(12).tolist()} for k, v in ENGINES.items()},
        "cases": cases,
        "head2xrview": [{"head": v, "view": c} for v, c in zip(views, xr, strict=True)],
        "bones": [
            {"joint": j, **dict(zip(RIGS, names, strict=True))} for j, names in BONES.items()
        ],
    }
