"""Per-frame arrays derived from a canonical clip: what training and evaluation read.

``derive_frames`` is the single place that turns motion into the model's view of it:

==============  ============  =========================================================
field           shape         meaning
==============  ============  =========================================================
rot6d           (F, 18, 6)    local rotations of the 18 non-root joints, 6D
root_pos        (F, 3)        pelvis world position, metres
root_quat       (F, 4)        pelvis world rotation, xyzw
positions       (F, 19, 3)    world joint positions of the clip's body, metres
tracker_pos     (F, 4, 3)     synthetic trackers, slot order (head, hands, waist)
tracker_quat    (F, 4, 4)     their orientations, xyzw
features        (F, 24)       network input (:func:`posecast.tracking.features.clip_features`)
contacts        (F, 2)        foot contact labels (left, right), 0/1
==============  ============  =========================================================
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from posecast.geometry.rotations import mat2r6d, quat2mat
from posecast.offline.dataset.contacts import foot_contacts
from posecast.offline.motion.clip import CanonicalClip
from posecast.skeleton import TOES
from posecast.tracking.features import clip_features, trackers_from_pose

FIELDS: dict[str, tuple[int, ...]] = {
    "rot6d": (18, 6),
    "root_pos": (3,),
    "root_quat": (4,),
    "positions": (19, 3),
    "tracker_pos": (4, 3),
    "tracker_quat": (4, 4),
    "features": (24,),
    "contacts": (2,),
}

Frames = dict[str, NDArray[np.float32]]


def derive_frames(clip: CanonicalClip) -> Frames:
    """All per-frame arrays of ``clip``, float32, in the layout of :data:`FIELDS`."""
    world_mat, world_pos = clip.fk()
    t_pos, t_quat = trackers_from_pose(world_mat, world_pos)
    out = {
        "rot6d": mat2r6d(quat2mat(clip.local_quat[:, 1:])),
        "root_pos": clip.root_pos,
        "root_quat": clip.local_quat[:, 0],
        "positions": world_pos,
        "tracker_pos": t_pos,
        "tracker_quat": t_quat,
        "features": clip_features(t_pos, t_quat, clip.fps),
        "contacts": foot_contacts(world_pos[:, list(TOES)], clip.fps),
    }
    return {k: np.ascontiguousarray(v, dtype=np.float32) for k, v in out.items()}


def concat_frames(parts: list[Frames]) -> tuple[Frames, NDArray[np.int64]]:
    """Concatenate per-clip arrays; returns them and clip start offsets ``(n_clips + 1,)``."""
    lengths = [len(p["features"]) for p in parts]
    starts = np.concatenate([[0], np.cumsum(lengths)]).astype(np.int64)
    if not parts:
        return {k: np.zeros((0, *s), np.float32) for k, s in FIELDS.items()}, starts
    return {k: np.concatenate([p[k] for p in parts], axis=0) for k in FIELDS}, starts
