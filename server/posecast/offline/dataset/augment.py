"""Augmentations of canonical clips: mirroring, speed perturbation, bone-length scaling.

Each returns a new clip; trackers, features and contacts are then derived from it
like from any clip (:func:`posecast.offline.dataset.frames.derive_frames`), so every label
stays consistent with its augmented motion.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from posecast.offline.motion.clip import CanonicalClip
from posecast.offline.motion.resample import resample
from posecast.skeleton import MIRROR_INDEX, PARENT, Joint


@dataclass(frozen=True)
class Augmentation:
    """Switches for training-time augmentation.

    Attributes:
        mirror: also use every clip mirrored left/right.
        speeds: playback-speed factors; each clip is used once per factor.
        bone_scale: body scale range ``(low, high)`` drawn per clip, plus
            ``bone_jitter`` relative noise per bone, applied to the tracker side
            only: targets stay on the canonical body, as the server calibrates
            every user to it.
    """

    mirror: bool = True
    speeds: tuple[float, ...] = (1.0,)
    bone_scale: tuple[float, float] = (1.0, 1.0)
    bone_jitter: float = 0.0

    @classmethod
    def none(cls) -> Augmentation:
        return cls(mirror=False)


def mirror(clip: CanonicalClip) -> CanonicalClip:
    """Reflect across the character's sagittal plane (x -> -x), swapping left and right."""
    idx = list(MIRROR_INDEX)
    q = clip.local_quat[:, idx].copy()
    q[..., 1] *= -1.0  # reflecting x negates the y and z rotation components
    q[..., 2] *= -1.0
    root = clip.root_pos.copy()
    root[:, 0] *= -1.0
    off = clip.offsets[idx].copy()
    off[:, 0] *= -1.0
    return clip.with_(local_quat=q, root_pos=root, offsets=off, name=clip.name + "~m")


def change_speed(clip: CanonicalClip, speed: float) -> CanonicalClip:
    """Play ``speed`` times as fast, keeping the frame rate."""
    if speed == 1.0:
        return clip
    out = resample(clip, clip.fps, speed=speed)
    return out.with_(name=f"{clip.name}~x{speed:g}")


def scale_bones(clip: CanonicalClip, rng: np.random.Generator, aug: Augmentation) -> CanonicalClip:
    """A clip of a differently proportioned body doing the same motion.

    Every bone is scaled by a body factor from ``aug.bone_scale`` times its own
    jitter; left and right bones share a factor so the body stays symmetric. The
    root path scales with the legs so the feet still meet the floor.
    """
    lo, hi = aug.bone_scale
    if lo == hi == 1.0 and aug.bone_jitter == 0.0:
        return clip
    body = rng.uniform(lo, hi)
    factors = np.ones(len(Joint))
    for j in Joint:
        if PARENT[j] is None or j.name.startswith("RIGHT_"):
            continue
        f = body * (1.0 + rng.uniform(-aug.bone_jitter, aug.bone_jitter))
        factors[j] = f
        if j.name.startswith("LEFT_"):
            factors[Joint["RIGHT_" + j.name[5:]]] = f
    off = clip.offsets * factors[:, None]
    legs = [Joint.LEFT_THIGH, Joint.LEFT_SHIN, Joint.LEFT_FOOT, Joint.LEFT_TOE]
    leg_scale = -off[legs, 1].sum() / -clip.offsets[legs, 1].sum()
    root = clip.root_pos * leg_scale
    return clip.with_(offsets=off, root_pos=root, name=f"{clip.name}~s{body:.2f}")
