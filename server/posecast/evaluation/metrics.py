"""Pose metrics. Positions in metres in, reported in centimetres.

Every function returns ``(sum, count)`` so clips of different lengths aggregate into
frame-weighted means across a whole split.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from posecast.skeleton import FEET, LOWER_BODY, TOES

F64 = NDArray[np.floating]
Acc = tuple[float, int]


def mpjpe(pred: F64, gt: F64, joints: list[int] | None = None) -> Acc:
    """Mean per-joint position error, cm. ``pred``, ``gt``: ``(T, 19, 3)``."""
    d = np.linalg.norm(pred - gt, axis=-1)  # (T, 19)
    if joints is not None:
        d = d[:, joints]
    return float(d.sum() * 100.0), int(d.size)


def lower_mpjpe(pred: F64, gt: F64) -> Acc:
    return mpjpe(pred, gt, [int(j) for j in LOWER_BODY])


def mpjve(pred: F64, gt: F64, fps: float) -> Acc:
    """Mean per-joint velocity error, cm/s."""
    d = np.linalg.norm(np.diff(pred, axis=0) - np.diff(gt, axis=0), axis=-1) * fps
    return float(d.sum() * 100.0), int(d.size)


def mpjae(pred: F64, gt: F64, fps: float) -> Acc:
    """Mean per-joint acceleration error, cm/s^2."""
    d = np.linalg.norm(np.diff(pred, 2, axis=0) - np.diff(gt, 2, axis=0), axis=-1) * fps**2
    return float(d.sum() * 100.0), int(d.size)


def foot_skate(pred: F64, gt_contacts: F64, fps: float) -> Acc:
    """Mean horizontal toe speed (cm/s) over the frames where the ground truth says contact."""
    toes = pred[:, [int(t) for t in TOES]][:, :, [0, 2]]  # (T, 2, 2) x, z
    speed = np.linalg.norm(np.diff(toes, axis=0), axis=-1) * fps  # (T-1, 2)
    on = gt_contacts[1:] > 0.5
    return float(speed[on].sum() * 100.0), int(on.sum())


def ground_penetration(pred: F64) -> Acc:
    """Mean depth (cm) of the lowest foot or toe joint below ``y = 0``, over all frames."""
    joints = [int(j) for j in (*FEET, *TOES)]
    depth = np.maximum(0.0, -pred[:, joints, 1].min(axis=1))
    return float(depth.sum() * 100.0), int(depth.size)


def implausible(scores: F64, threshold_m: float) -> Acc:
    """Share of frames whose anomaly error exceeds the threshold (as a fraction)."""
    return float((scores > threshold_m).sum()), int(scores.size)


class Accumulator:
    """Named ``(sum, count)`` pairs; ``means()`` gives the frame-weighted averages."""

    def __init__(self) -> None:
        self.sums: dict[str, float] = {}
        self.counts: dict[str, int] = {}

    def add(self, name: str, acc: Acc) -> None:
        self.sums[name] = self.sums.get(name, 0.0) + acc[0]
        self.counts[name] = self.counts.get(name, 0) + acc[1]

    def means(self) -> dict[str, float]:
        return {
            k: self.sums[k] / self.counts[k] if self.counts[k] else float("nan") for k in self.sums
        }
