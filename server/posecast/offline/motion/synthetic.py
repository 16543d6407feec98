"""Procedural motion: a walking, turning, pausing figure on the canonical skeleton.

Used by the tests (which must run without the CMU data), the demo and the headset
simulator's built-in fixture. :func:`write_fixture_bvh` writes a clip in the layout
of a real rig (joint names, extra zero-offset joints, units, channel order, the
synthetic T-pose first frame), so the retargeting code paths run on it exactly as
on the CMU files.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from posecast.geometry.rotations import aa2quat, euler2mat, mat2quat, quat_conj, quat_mul
from posecast.offline.motion.bvh import write_bvh
from posecast.offline.motion.clip import CanonicalClip
from posecast.offline.motion.retarget import align_floor
from posecast.offline.motion.rig import builtin_rigs
from posecast.skeleton import PARENTS, REST_PELVIS_HEIGHT_M, Joint, reference_offsets


def walk_clip(
    seconds: float = 4.0, fps: float = 60.0, seed: int = 0, name: str = "walk"
) -> CanonicalClip:
    """A figure that walks a gentle curve, pauses mid-way, and swings its arms.

    Deterministic for a given ``seed``; the seed varies stride, speed and style.
    """
    rng = np.random.default_rng(seed)
    n = max(2, round(seconds * fps))
    t = np.arange(n) / fps
    step_hz = rng.uniform(0.8, 1.0)
    amp = rng.uniform(0.8, 1.2)
    # Walk, stand still for the middle fifth, walk again.
    gait = np.clip(np.abs(t / seconds - 0.5) * 10.0 - 1.0, 0.0, 1.0)
    phase = 2 * np.pi * step_hz * np.cumsum(gait) / fps
    s = np.sin(phase)
    yaw = 0.4 * np.sin(0.25 * t + rng.uniform(0, np.pi))
    speed = 1.2 * amp * gait
    heading = np.stack([np.sin(yaw), np.zeros(n), np.cos(yaw)], axis=-1)
    root = np.cumsum(heading * speed[:, None] / fps, axis=0)
    root[:, 1] = REST_PELVIS_HEIGHT_M - 0.03 * gait * (1 - np.cos(2 * phase)) * 0.5

    e = np.zeros((n, len(Joint), 3))  # (F, 19, 3) Euler angles, order ZYX
    e[:, Joint.PELVIS] = np.stack([0.03 * s * gait, yaw, 0.02 * np.cos(phase)], -1)
    e[:, Joint.SPINE, 2] = 0.05 + 0.02 * s
    e[:, Joint.CHEST, 1] = -0.15 * s * gait * amp
    e[:, Joint.NECK, 2] = -0.05
    e[:, Joint.HEAD, 1] = 0.1 * np.sin(0.7 * t)
    for side, sign in (("LEFT", 1.0), ("RIGHT", -1.0)):
        ph = s * sign
        e[:, Joint[f"{side}_UPPER_ARM"]] = np.stack(
            [np.full(n, -1.25 * sign), sign * 0.45 * ph * gait * amp, np.zeros(n)], -1
        )
        e[:, Joint[f"{side}_FOREARM"], 1] = sign * (0.3 + 0.2 * gait * np.maximum(ph, 0))
        e[:, Joint[f"{side}_HAND"], 2] = 0.1 * ph
        e[:, Joint[f"{side}_THIGH"], 2] = -0.45 * ph * gait * amp
        e[:, Joint[f"{side}_SHIN"], 2] = (
            0.9 * gait * amp * np.maximum(np.sin(phase * sign + 1.2), 0) ** 2
        )
        e[:, Joint[f"{side}_FOOT"], 2] = 0.2 * ph * gait
        e[:, Joint[f"{side}_TOE"], 2] = -0.1 * gait * np.maximum(-ph, 0)
    local = mat2quat(euler2mat(e, "ZYX"))
    clip = CanonicalClip(name=name, subject="synthetic", fps=fps, local_quat=local, root_pos=root)
    return align_floor(clip)


# Extra source joints a layout inserts: name -> (parent in source, child it precedes).
# They have zero offsets, like CMU's LHipJoint/Neck/LeftShoulder, and get a rotation
# that twists about the child's bone, compensated in the child, so the motion is
# unchanged but retargeting has to compose them.
_MB_INSERTS = {
    "LHipJoint": "LEFT_THIGH",
    "RHipJoint": "RIGHT_THIGH",
    "Neck": "NECK",
    "LeftShoulder": "LEFT_UPPER_ARM",
    "RightShoulder": "RIGHT_UPPER_ARM",
}


def write_fixture_bvh(path: str | Path, clip: CanonicalClip, layout: str = "posecast") -> None:
    """Write ``clip`` as BVH laid out like a built-in rig: ``posecast``, ``cmu_mb``, ``cmu_daz``.

    The reference body is written in the rig's length unit, with its channel order,
    and (for the CMU rigs) a T-pose first frame.
    """
    rig = {r.name: r for r in builtin_rigs()}[layout]
    off = reference_offsets()
    q = clip.local_quat
    names = [rig.joints[j].joint if not rig.joints[j].end_site else "" for j in Joint]
    parents = list(PARENTS)
    offsets = [off[j] for j in Joint]
    quats = [q[:, j] for j in Joint]
    end_sites: dict[int, NDArray[np.float64]] = {}
    order = {"posecast": "ZYX", "cmu_mb": "ZYX", "cmu_daz": "ZXY"}[layout]
    if layout == "cmu_mb":
        t = np.arange(clip.n_frames) / clip.fps
        for k, (extra, child_name) in enumerate(_MB_INSERTS.items()):
            child = int(Joint[child_name])
            axis = off[child] / np.linalg.norm(off[child])
            twist = aa2quat(axis[None, :] * (0.3 * np.sin(2.0 * t + k))[:, None])  # (F, 4)
            new = len(names)
            names.append(extra)
            parents.append(parents[child])
            offsets.append(np.zeros(3))
            quats.append(twist)
            parents[child] = new
            quats[child] = quat_mul(quat_conj(twist), quats[child])
    if layout == "cmu_daz":
        for toe in (Joint.LEFT_TOE, Joint.RIGHT_TOE):
            end_sites[int(PARENTS[toe])] = off[toe]
    keep = [i for i, nm in enumerate(names) if nm]
    order_idx = _topological(parents, keep)
    remap = {old: new for new, old in enumerate(order_idx)}
    w_names = [names[i] for i in order_idx]
    w_parents = [-1 if parents[i] < 0 else remap[parents[i]] for i in order_idx]
    w_off = np.array([offsets[i] for i in order_idx])
    w_q = np.stack([quats[i] for i in order_idx], axis=1)
    w_ends = {remap[k]: v for k, v in end_sites.items()}
    root = clip.root_pos
    if rig.first_frame_is_tpose:
        tpose = np.zeros_like(w_q[:1])
        tpose[..., 3] = 1.0
        w_q = np.concatenate([tpose, w_q], axis=0)
        root = np.concatenate([root[:1], root], axis=0)
    write_bvh(
        path,
        names=w_names,
        parents=w_parents,
        offsets=w_off,
        root_pos=root,
        local_quat=w_q,
        frame_time_s=1.0 / clip.fps,
        end_sites=w_ends,  # type: ignore[arg-type]
        order=order,
        scale=1.0 / rig.unit_m,
    )


def _topological(parents: list[int], keep: list[int]) -> list[int]:
    """Depth-first order of the kept joints starting from the root."""
    kids: dict[int, list[int]] = {i: [] for i in keep}
    roots: list[int] = []
    for i in keep:
        (roots if parents[i] < 0 else kids[parents[i]]).append(i)
    out: list[int] = []

    def walk(i: int) -> None:
        out.append(i)
        for c in kids[i]:
            walk(c)

    for r in roots:
        walk(r)
    return out
