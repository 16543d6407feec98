"""The built-in fixture: a procedural walk on the canonical skeleton (no data files).

The figure walks a gentle curve, stands still for the middle fifth of the clip and
walks on, swinging its arms; a seed varies stride, speed and style. Everything is
deterministic for a given seed.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from posecast_client.bvh import write_bvh
from posecast_client.rotations import F64, euler2mat, fk, mat2quat
from posecast_client.skeleton import (
    JOINT_NAMES,
    PARENTS,
    REST_PELVIS_HEIGHT_M,
    Joint,
    reference_offsets,
)


def walk_motion(seconds: float = 10.0, fps: float = 60.0, seed: int = 0) -> tuple[F64, F64]:
    """Canonical motion of the walk: ``(root_pos (F, 3), local_quat (F, 19, 4))``.

    The feet stand on the floor (``y = 0``); the pelvis starts at the origin in X/Z.
    """
    rng = np.random.default_rng(seed)
    n = max(2, round(seconds * fps))
    t = np.arange(n) / fps
    step_hz, amp = rng.uniform(0.8, 1.0), rng.uniform(0.8, 1.2)
    gait = np.clip(np.abs(t / (n / fps) - 0.5) * 10.0 - 1.0, 0.0, 1.0)  # 0 while standing
    phase = 2 * np.pi * step_hz * np.cumsum(gait) / fps
    s = np.sin(phase)
    yaw = 0.4 * np.sin(0.25 * t + rng.uniform(0, np.pi))
    heading = np.stack([np.sin(yaw), np.zeros(n), np.cos(yaw)], axis=-1)  # (F, 3)
    root = np.cumsum(heading * (1.2 * amp * gait)[:, None] / fps, axis=0)
    root[:, 1] = REST_PELVIS_HEIGHT_M - 0.015 * gait * (1 - np.cos(2 * phase))

    e = np.zeros((n, len(Joint), 3))  # (F, 19, 3) Euler angles, order ZYX
    e[:, Joint.PELVIS] = np.stack([0.03 * s * gait, yaw, 0.02 * np.cos(phase)], -1)
    e[:, Joint.SPINE, 2] = 0.05 + 0.02 * s
    e[:, Joint.CHEST, 1] = -0.15 * s * gait * amp
    e[:, Joint.NECK, 2] = -0.05
    e[:, Joint.HEAD, 1] = 0.1 * np.sin(0.7 * t)
    for side, sign in (("LEFT", 1.0), ("RIGHT", -1.0)):
        ph = s * sign
        arm = np.stack([np.full(n, -1.25 * sign), sign * 0.45 * ph * gait * amp, np.zeros(n)], -1)
        e[:, Joint[f"{side}_UPPER_ARM"]] = arm  # arms down from the T-pose, swinging
        e[:, Joint[f"{side}_FOREARM"], 1] = sign * (0.3 + 0.2 * gait * np.maximum(ph, 0))
        e[:, Joint[f"{side}_HAND"], 2] = 0.1 * ph
        e[:, Joint[f"{side}_THIGH"], 2] = -0.45 * ph * gait * amp
        e[:, Joint[f"{side}_SHIN"], 2] = (
            0.9 * gait * amp * np.maximum(np.sin(phase * sign + 1.2), 0) ** 2
        )
        e[:, Joint[f"{side}_FOOT"], 2] = 0.2 * ph * gait
        e[:, Joint[f"{side}_TOE"], 2] = -0.1 * gait * np.maximum(-ph, 0)
    local = euler2mat(e, "ZYX")  # (F, 19, 3, 3)
    _, pos = fk(local, root, reference_offsets(), PARENTS)
    toes = pos[:, [Joint.LEFT_TOE, Joint.RIGHT_TOE], 1].min(axis=1)
    root[:, 1] += 0.02 - np.percentile(toes, 5.0)  # toe joints 2 cm above the floor
    return root, mat2quat(local)


def write_walk_bvh(
    path: str | Path, seconds: float = 4.0, fps: float = 60.0, seed: int = 0
) -> None:
    """The walk as a BVH file on the canonical skeleton (joint names as on the wire)."""
    root, local = walk_motion(seconds, fps, seed)
    write_bvh(
        path,
        names=JOINT_NAMES,
        parents=PARENTS,
        offsets=reference_offsets(),
        root_pos=root,
        local_quat=local,
        frame_time_s=1.0 / fps,
    )
