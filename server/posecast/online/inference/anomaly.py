"""Pose plausibility scores from the anomaly autoencoder (paper Sec. 3.2.1).

``R`` of a pose is the mean distance, over the 8 lower-body joints, between the pose
and its reconstruction: positions go into the character frame, through the AE, and
back through FK with the waist's own (heading-free) rotation.

The scorer runs the AE's artifact (:mod:`posecast.online.inference.artifact`, ONNX
Runtime), so it lives beside it: the ``onnx`` and ``torch`` backends' candidate pool
scores with it, and so does the evaluation's ``implausible_rate``; the engine itself
only reads the scores a backend's pool returns (the ``native`` pool runs the same AE
in C).
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from posecast.body.batch_fk import fk32
from posecast.geometry.rotations import quat2mat
from posecast.online.inference.artifact import Artifact
from posecast.skeleton import LOWER_BODY, Joint

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
        return self.score_mats(world_pos, waist_pos, quat2mat(waist_quat), repeat)

    def score_mats(self, world_pos: F64, root_pos: F64, root_mat: F64, repeat: int = 1) -> F64:
        """:meth:`score` with the pelvis pose as ``(B / repeat, 3)`` positions and
        ``(B / repeat, 3, 3)`` rotation matrices (one per pose for a model that
        predicts the pelvis itself)."""
        yaw = np.arctan2(root_mat[:, 0, 2], root_mat[:, 2, 2])  # heading of the +Z axis
        c, s = np.cos(yaw), np.sin(yaw)
        z, o = np.zeros_like(c), np.ones_like(c)
        inv_yaw = np.stack([c, z, -s, z, o, z, s, z, c], axis=-1).reshape(-1, 3, 3)
        root = (inv_yaw @ root_mat).astype(np.float32)  # heading removed
        origin = np.array(root_pos, dtype=np.float64, copy=True)
        origin[:, 1] = 0.0
        angle = -yaw
        if repeat > 1:
            origin, angle = np.repeat(origin, repeat, 0), np.repeat(angle, repeat, 0)
            root = np.repeat(root, repeat, 0)
        rel = world_pos - origin[:, None, :]
        local = rotate_y(rel, angle)  # (B, 19, 3)
        local = np.ascontiguousarray(local, dtype=np.float32)
        (rot,) = self.artifact.run(local_positions=local.reshape(len(local), 57))
        _, rec = fk32(rot, root, local[:, Joint.PELVIS], want_mats=False, joints=_LOWER_T)
        err: F64 = np.linalg.norm(rec[:, _LOWER] - local[:, _LOWER], axis=-1).mean(axis=-1)
        return err


def rotate_y(v: F64, angle: F64) -> F64:
    """Rotate ``v (B, K, 3)`` about +Y by ``angle (B,)`` radians."""
    c, s = np.cos(angle)[:, None], np.sin(angle)[:, None]
    x, z = v[..., 0], v[..., 2]
    return np.stack([c * x + s * z, v[..., 1], -s * x + c * z], axis=-1)
