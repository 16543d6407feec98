"""Retarget a source BVH onto the canonical skeleton.

Retargeting works in world space, which is what makes skipped source joints (CMU's
``LowerBack``, zero-offset ``Neck``, collars) compose for free:

1. Source FK gives every source joint's world rotation ``G_src`` and position.
2. For a canonical joint ``j`` whose bone runs to a child ``c``, a fixed rest
   correction ``C_j`` turns the canonical rest bone onto the source's rest bone
   (both rest poses are T-poses facing +Z, so world rest rotations are identity).
3. Each frame, ``G_j = S_t @ G_src @ C_j``, where the swing ``S_t`` is the smallest
   rotation making the canonical bone point exactly along the source bone
   ``p_src[c] - p_src[j]``. Twist comes from the source joint; leaves (head, hands,
   toes) and the pelvis take ``G_src`` as it is.
4. Local rotations follow as ``L_j = G_parent^T G_j``.
5. The root path is scaled by canonical / source leg length, so strides fit the
   canonical legs, then shifted so the feet stand on ``y = 0`` (see
   :func:`align_floor`).
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from posecast.errors import BvhError
from posecast.geometry.fk import fk_mat, world2local_mat
from posecast.geometry.rotations import mat2quat, quat2mat, vecs2quat
from posecast.offline.motion.bvh import Bvh
from posecast.offline.motion.clip import CanonicalClip
from posecast.offline.motion.resample import resample
from posecast.offline.motion.rig import Rig, SourceRef
from posecast.skeleton import (
    PARENTS,
    REST_PELVIS_HEIGHT_M,
    REST_TOE_HEIGHT_M,
    Joint,
    reference_offsets,
)

TARGET_FPS = 60.0

# The child each canonical bone aims at; joints not listed keep the source rotation.
_AIM: dict[Joint, Joint] = {
    Joint.SPINE: Joint.CHEST,
    Joint.CHEST: Joint.NECK,
    Joint.NECK: Joint.HEAD,
    Joint.LEFT_UPPER_ARM: Joint.LEFT_FOREARM,
    Joint.LEFT_FOREARM: Joint.LEFT_HAND,
    Joint.RIGHT_UPPER_ARM: Joint.RIGHT_FOREARM,
    Joint.RIGHT_FOREARM: Joint.RIGHT_HAND,
    Joint.LEFT_THIGH: Joint.LEFT_SHIN,
    Joint.LEFT_SHIN: Joint.LEFT_FOOT,
    Joint.LEFT_FOOT: Joint.LEFT_TOE,
    Joint.RIGHT_THIGH: Joint.RIGHT_SHIN,
    Joint.RIGHT_SHIN: Joint.RIGHT_FOOT,
    Joint.RIGHT_FOOT: Joint.RIGHT_TOE,
}

F64 = NDArray[np.float64]


def _source_world(bvh: Bvh, unit_m: float, rest: bool) -> tuple[F64, F64]:
    """World rotations ``(F, J, 3, 3)`` and positions ``(F, J, 3)`` of the source, metres."""
    rot, trans = bvh.local_transforms()
    if rest:
        rot = np.broadcast_to(np.eye(3), rot[:1].shape).copy()
        trans = np.broadcast_to(bvh.offsets(), trans[:1].shape).copy()
    trans = trans * unit_m
    root = trans[:, 0, :].copy()
    trans[:, 0, :] = 0.0
    return fk_mat(rot, root, trans, bvh.parents)


def _ref_pos(bvh: Bvh, ref: SourceRef, gm: F64, gp: F64, unit_m: float) -> F64:
    """World position of a mapped source joint or End Site, ``(F, 3)``."""
    i = bvh.index(ref.joint)
    if not ref.end_site:
        return gp[:, i]
    end = np.asarray(bvh.joints[i].end_site, dtype=np.float64) * unit_m
    return np.asarray(gp[:, i] + np.einsum("fab,b->fa", gm[:, i], end), dtype=np.float64)


def _leg_length(pelvis_y: float, toe_l_y: float, toe_r_y: float) -> float:
    return pelvis_y - 0.5 * (toe_l_y + toe_r_y)


def _nominal_fps(frame_time_s: float) -> float:
    """The frame rate a BVH frame time stands for.

    Files store the frame time rounded (CMU ``0.0083333``, ``write_bvh`` eight
    decimals), so ``1 / t`` lands a little off the real rate: enough to resample a
    clip that is already at the target rate, and to lose its last frame when its
    duration is a whole number of output frames. A rate within 0.01 % of a whole
    number is taken to be that number; genuine rates such as 29.97 stay as they are.
    """
    fps = 1.0 / frame_time_s
    whole = round(fps)
    return float(whole) if whole > 0 and abs(fps - whole) <= 1e-4 * fps else fps


def retarget(
    bvh: Bvh, rig: Rig, *, name: str, subject: str, fps: float = TARGET_FPS
) -> CanonicalClip:
    """Retarget ``bvh`` (already matched to ``rig``) onto the canonical skeleton at ``fps``."""
    if rig.first_frame_is_tpose and bvh.n_frames > 0:
        bvh = Bvh(bvh.joints, bvh.frame_time_s, bvh.motion[1:], bvh.source)
    if bvh.n_frames < 2:
        raise BvhError("fewer than 2 frames of motion", file=bvh.source)
    gm, gp = _source_world(bvh, rig.unit_m, rest=False)
    rm, rp = _source_world(bvh, rig.unit_m, rest=True)
    can_off = reference_offsets()
    n_frames = bvh.n_frames
    world = np.empty((n_frames, len(Joint), 3, 3))
    for j in Joint:
        ref = rig.joints[j]
        g_src = gm[:, bvh.index(ref.joint)]
        aim = _AIM.get(j)
        if aim is None:
            world[:, j] = g_src
            continue
        child_ref = rig.joints[aim]
        rest_dir = _ref_pos(bvh, child_ref, rm, rp, rig.unit_m) - _ref_pos(
            bvh, ref, rm, rp, rig.unit_m
        )
        c_j = vecs2quat(can_off[aim], rest_dir[0])  # (4,)
        g = g_src @ quat2mat(c_j)
        bone_now = _ref_pos(bvh, child_ref, gm, gp, rig.unit_m) - _ref_pos(
            bvh, ref, gm, gp, rig.unit_m
        )
        predicted = np.einsum("fab,b->fa", g, can_off[aim])
        swing = quat2mat(vecs2quat(predicted, bone_now))
        world[:, j] = swing @ g
    local = world2local_mat(world, PARENTS)
    local_quat = mat2quat(local)

    # Root path: scale source metres to canonical leg length.
    src_leg = _leg_length(
        float(rp[0, bvh.index(rig.joints[Joint.PELVIS].joint), 1]),
        float(_ref_pos(bvh, rig.joints[Joint.LEFT_TOE], rm, rp, rig.unit_m)[0, 1]),
        float(_ref_pos(bvh, rig.joints[Joint.RIGHT_TOE], rm, rp, rig.unit_m)[0, 1]),
    )
    can_leg = REST_PELVIS_HEIGHT_M - REST_TOE_HEIGHT_M
    scale = can_leg / src_leg if src_leg > 1e-6 else 1.0
    root = gp[:, bvh.index(rig.joints[Joint.PELVIS].joint)] * scale
    clip = CanonicalClip(
        name=name,
        subject=subject,
        fps=_nominal_fps(bvh.frame_time_s),
        local_quat=local_quat,
        root_pos=root,
        rig=rig.name,
    )
    if abs(clip.fps - fps) > 1e-6:
        clip = resample(clip, fps)
    if rig.align_floor:
        clip = align_floor(clip)
    return clip


def align_floor(clip: CanonicalClip, percentile: float = 5.0) -> CanonicalClip:
    """Shift the clip vertically so the feet stand on ``y = 0``.

    The lower toe's height at the ``percentile``-th percentile over the clip is put
    at the toe joint's rest height. A low percentile, not the minimum, so one
    glitchy frame cannot lift the whole clip; not the median, so jumps and climbs
    keep their height.
    """
    _, pos = clip.fk()
    toes = pos[:, [Joint.LEFT_TOE, Joint.RIGHT_TOE], 1].min(axis=1)
    shift = REST_TOE_HEIGHT_M - float(np.percentile(toes, percentile))
    root = clip.root_pos.copy()
    root[:, 1] += shift
    return clip.with_(root_pos=root)
