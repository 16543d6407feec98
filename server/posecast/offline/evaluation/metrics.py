"""Pose metrics. Positions in metres in, reported in centimetres.

Every function returns ``(sum, count)`` so clips of different lengths aggregate into
frame-weighted means across a whole split.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from posecast.body.clearance import toe_steps
from posecast.skeleton import FEET, LOWER_BODY, PARENTS, TOES, Joint

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
    speed = toe_steps(pred, fps)  # (T-1, 2)
    on = gt_contacts[1:] > 0.5
    return float(speed[on].sum() * 100.0), int(on.sum())


def ground_penetration(pred: F64) -> Acc:
    """Mean depth (cm) of the lowest foot or toe joint below ``y = 0``, over all frames."""
    joints = [int(j) for j in (*FEET, *TOES)]
    depth = np.maximum(0.0, -pred[:, joints, 1].min(axis=1))
    return float(depth.sum() * 100.0), int(depth.size)


def root_pe(pred: F64, gt: F64) -> Acc:
    """Pelvis position error, cm (the headset-only model predicts the pelvis)."""
    return mpjpe(pred, gt, [int(Joint.PELVIS)])


def hand_pe(pred: F64, gt: F64) -> Acc:
    """Position error of both hands, cm."""
    return mpjpe(pred, gt, [int(Joint.LEFT_HAND), int(Joint.RIGHT_HAND)])


def head_pe(pred: F64, gt: F64) -> Acc:
    """Position error of the head joint, cm."""
    return mpjpe(pred, gt, [int(Joint.HEAD)])


def _geodesic_deg(a: F64, b: F64) -> F64:
    """Angle between rotation matrices ``(..., 3, 3)``, degrees."""
    rel = np.swapaxes(a, -1, -2) @ b
    cos = np.clip((np.trace(rel, axis1=-2, axis2=-1) - 1.0) / 2.0, -1.0, 1.0)
    return np.asarray(np.degrees(np.arccos(cos)), dtype=np.float64)


def hand_rot_err(pred_world_mat: F64, gt_world_mat: F64) -> Acc:
    """Geodesic angle between predicted and true *world* rotations of both hands,
    degrees (what a user holding the controllers sees)."""
    hands = [int(Joint.LEFT_HAND), int(Joint.RIGHT_HAND)]
    d = _geodesic_deg(pred_world_mat[:, hands], gt_world_mat[:, hands])
    return float(d.sum()), int(d.size)


def local_rotations(world_mat: F64) -> F64:
    """World joint rotations ``(T, 19, 3, 3)`` -> local ones (the pelvis keeps its world
    rotation)."""
    local = np.array(world_mat, dtype=np.float64, copy=True)
    for j, p in enumerate(PARENTS):
        if p >= 0:
            local[:, j] = np.swapaxes(world_mat[:, p], -1, -2) @ world_mat[:, j]
    return local


def mpjre(pred_world_mat: F64, gt_world_mat: F64) -> Acc:
    """Mean per-joint rotation error, degrees: the geodesic angle between predicted and
    true *local* rotations of all 19 joints (the pelvis: its world rotation)."""
    d = _geodesic_deg(local_rotations(pred_world_mat), local_rotations(gt_world_mat))  # (T, 19)
    return float(d.sum()), int(d.size)


def jitter(pred: F64, fps: float) -> Acc:
    """Mean jerk of the joints, m/s^3: the norm of the third difference of the positions
    times ``fps^3``, over every joint and frame (lower is smoother)."""
    d = np.linalg.norm(np.diff(pred, 3, axis=0), axis=-1) * fps**3
    return float(d.sum()), int(d.size)


def present(pred: F64, gt: F64, delay: int) -> dict[str, Acc]:
    """The error a room-mate sees: the pose emitted at tick ``n`` (``pred`` is aligned
    with its own frames, emitted ``delay`` ticks after them) against the truth at frame
    ``n``, over ``n >= delay`` (nothing is emitted before). ``delay = 0``: the aligned
    errors."""
    T = len(pred) - delay
    shown, now = pred[: max(T, 0)], gt[delay : delay + max(T, 0)]
    return {
        "present_mpjpe_cm": mpjpe(shown, now),
        "present_lower_mpjpe_cm": lower_mpjpe(shown, now),
        "present_head_pe_cm": head_pe(shown, now),
        "present_hand_pe_cm": hand_pe(shown, now),
        "present_root_pe_cm": root_pe(shown, now),
    }


def flag_rates(flags: dict[str, NDArray[np.bool_]]) -> dict[str, Acc]:
    """Per-frame plausibility flags of one clip (:func:`posecast.offline.evaluation.
    plausibility.flags`) -> ``flagged_rate`` (any category) and ``flagged_<category>_rate``
    as ``(count, frames)`` pairs (fractions once averaged)."""
    frames = len(next(iter(flags.values())))
    out = {f"flagged_{c}_rate": (float(f.sum()), frames) for c, f in flags.items()}
    out["flagged_rate"] = (float(np.logical_or.reduce(list(flags.values())).sum()), frames)
    return out


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
