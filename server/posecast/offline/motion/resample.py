"""Time resampling of canonical clips: frame-rate conversion and speed perturbation."""

from __future__ import annotations

import numpy as np

from posecast.geometry.rotations import quat_slerp
from posecast.offline.motion.clip import CanonicalClip


def resample(clip: CanonicalClip, fps: float, speed: float = 1.0) -> CanonicalClip:
    """Resample ``clip`` to ``fps``, played ``speed`` times as fast.

    Rotations are slerped and the root path is lerped between the two nearest source
    frames. ``speed=1.1`` gives a clip 10 % shorter in which everything moves 10 %
    faster (the speed-perturbation augmentation).
    """
    if fps <= 0 or speed <= 0:
        raise ValueError("fps and speed must be positive")
    duration = (clip.n_frames - 1) / clip.fps  # seconds of source motion
    n_out = int(np.floor(duration / speed * fps + 1e-9)) + 1
    src_t = np.arange(n_out) * speed / fps * clip.fps  # fractional source frame index
    i0 = np.clip(np.floor(src_t).astype(int), 0, clip.n_frames - 1)
    i1 = np.minimum(i0 + 1, clip.n_frames - 1)
    frac = src_t - i0
    q = quat_slerp(clip.local_quat[i0], clip.local_quat[i1], frac[:, None])
    root = clip.root_pos[i0] * (1.0 - frac[:, None]) + clip.root_pos[i1] * frac[:, None]
    return clip.with_(fps=float(fps), local_quat=q, root_pos=root)
