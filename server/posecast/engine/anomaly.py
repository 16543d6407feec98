"""Pose plausibility scores from the anomaly autoencoder (paper Sec. 3.2.1).

``R`` of a pose is the mean distance, over the 8 lower-body joints, between the pose
and its reconstruction: positions go into the character frame, through the AE, and
back through FK with the waist's own (heading-free) rotation.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from posecast.engine.kinematics32 import fk32
from posecast.geometry.rotations import quat2mat
from posecast.inference.artifact import Artifact
from posecast.skeleton import LOWER_BODY, Joint
from posecast.tracking import character_frame, deyaw_quat

F64 = NDArray[np.floating]
_LOWER = [int(j) for j in LOWER_BODY]
_LOWER_T = tuple(_LOWER)


class AnomalyScorer:
    """Scores batches of world poses; ``threshold_m`` is the p99 error on real poses."""

    def __init__(self, artifact: Artifact) -> None:
        self.artifact = artifact
        self.threshold_m = float(artifact.meta.get("implausible_threshold_m", float("nan")))

    def score(self, world_pos: F64, waist_pos: F64, waist_quat: F64, repeat: int = 1) -> F64:
        """Lower-body reconstruction error ``R (B,)`` in metres of world poses
        ``(B, 19, 3)`` with their waist trackers ``(B / repeat, 3)`` / ``(B / repeat, 4)``.

        With ``repeat = N`` consecutive groups of ``N`` poses share one waist (the
        ``N`` samples of one player), and the frame math runs once per group.
        """
        origin, inv_yaw = character_frame(waist_pos, waist_quat)
        root = quat2mat(deyaw_quat(waist_quat)).astype(np.float32)
        if repeat > 1:
            origin, inv_yaw = np.repeat(origin, repeat, 0), np.repeat(inv_yaw, repeat, 0)
            root = np.repeat(root, repeat, 0)
        rel = world_pos - origin[:, None, :]
        local = _rotate_y(rel, inv_yaw)  # (B, 19, 3)
        local = np.ascontiguousarray(local, dtype=np.float32)
        (rot,) = self.artifact.run(local_positions=local.reshape(len(local), 57))
        _, rec = fk32(rot, root, local[:, Joint.PELVIS], want_mats=False, joints=_LOWER_T)
        err: F64 = np.linalg.norm(rec[:, _LOWER] - local[:, _LOWER], axis=-1).mean(axis=-1)
        return err


def _rotate_y(v: F64, q_yaw: F64) -> F64:
    """Rotate ``v (B, K, 3)`` by pure-yaw quaternions ``(B, 4)`` (cheaper than a full apply)."""
    ang = 2.0 * np.arctan2(q_yaw[:, 1], q_yaw[:, 3])
    c, s = np.cos(ang)[:, None], np.sin(ang)[:, None]
    x, z = v[..., 0], v[..., 2]
    return np.stack([c * x + s * z, v[..., 1], -s * x + c * z], axis=-1)
