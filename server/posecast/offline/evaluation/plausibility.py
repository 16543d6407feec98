"""An independent plausibility measure: physical checks of a pose, no network involved.

``implausible_rate`` is the anomaly autoencoder's own score, the quantity SSI
minimises, so it cannot show whether SSI helps. These checks look at the pose alone,
per frame, in four categories:

* ``self_intersection``: capsules around the thighs, shins and feet (hip-knee,
  knee-ankle, ankle-toe) of one leg overlap a capsule of the other leg by more than
  a margin.
* ``joint_angle``: a knee bent backwards (hyperextension), a knee bent beyond its
  range or sideways, a hip flexed, extended, abducted or adducted beyond human range
  (angles of the local rotations, see :func:`joint_angles`).
* ``floor``: a foot or toe joint more than 2 cm below the floor (``y = 0``).
* ``skate``: a toe near the floor (in contact by its own height) sliding faster than
  a bound.

Every threshold was chosen so that the ground truth (the mocap the models are
trained on, reference body) is flagged on at most 0.5 % of frames per category on
the training and validation splits (``posecast eval`` reports the ground truth's own
rates beside every variant); docs/evaluation.md gives the figures. Positions are on
the reference body (1.75 m), metres, +Y up, as the evaluation reconstructs them.
Pure numpy.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from posecast.body.clearance import toe_steps
from posecast.offline.evaluation.metrics import local_rotations
from posecast.skeleton import Joint

F64 = NDArray[np.float64]
B = NDArray[np.bool_]

CATEGORIES = ("self_intersection", "joint_angle", "floor", "skate")

_L = (Joint.LEFT_THIGH, Joint.LEFT_SHIN, Joint.LEFT_FOOT, Joint.LEFT_TOE)
_R = (Joint.RIGHT_THIGH, Joint.RIGHT_SHIN, Joint.RIGHT_FOOT, Joint.RIGHT_TOE)
_SEGMENTS = ("thigh", "shin", "foot")  # (hip, knee), (knee, ankle), (ankle, toe)


@dataclass(frozen=True, slots=True)
class Thresholds:
    """The checks' bounds (metres, degrees, metres per second)."""

    # Capsule radii around each leg segment, and how deep two may overlap unflagged.
    radius_m: tuple[float, float, float] = (0.05, 0.04, 0.03)  # thigh, shin, foot
    overlap_m: float = 0.04
    # Knee: flexion range (negative is hyperextension) and sideways bend.
    knee_flex_deg: tuple[float, float] = (-10.0, 160.0)
    knee_side_deg: float = 25.0
    # Hip: flexion (forward, +) and abduction (outward, +) ranges.
    hip_flex_deg: tuple[float, float] = (-45.0, 135.0)
    hip_abd_deg: tuple[float, float] = (-45.0, 65.0)
    # Floor: how far below y = 0 a foot or toe joint may go.
    floor_m: float = 0.02
    # Skate: a toe below this height counts as in contact; faster than this slides.
    contact_height_m: float = 0.03
    skate_speed_m_s: float = 1.2


DEFAULT = Thresholds()


def _segment_distance(p0: F64, p1: F64, q0: F64, q1: F64) -> F64:
    """Closest distance between segments ``p0-p1`` and ``q0-q1``, batched over ``(..., 3)``."""
    d1, d2, r = p1 - p0, q1 - q0, p0 - q0
    a = np.einsum("...i,...i->...", d1, d1)
    e = np.einsum("...i,...i->...", d2, d2)
    f = np.einsum("...i,...i->...", d2, r)
    c = np.einsum("...i,...i->...", d1, r)
    b = np.einsum("...i,...i->...", d1, d2)
    denom = a * e - b * b
    eps = 1e-12
    s = np.where(denom > eps, np.clip((b * f - c * e) / np.maximum(denom, eps), 0.0, 1.0), 0.0)
    t = (b * s + f) / np.maximum(e, eps)
    # t outside [0, 1]: clamp it and recompute s for the clamped t.
    t_lo, t_hi = t < 0.0, t > 1.0
    s = np.where(t_lo, np.clip(-c / np.maximum(a, eps), 0.0, 1.0), s)
    s = np.where(t_hi, np.clip((b - c) / np.maximum(a, eps), 0.0, 1.0), s)
    t = np.clip(t, 0.0, 1.0)
    closest = (p0 + d1 * s[..., None]) - (q0 + d2 * t[..., None])
    return np.asarray(np.linalg.norm(closest, axis=-1), dtype=np.float64)


def leg_overlap(positions: F64, th: Thresholds = DEFAULT) -> F64:
    """Deepest overlap (metres, negative when apart) between a left-leg capsule and a
    right-leg capsule, per frame: ``(T, 19, 3)`` -> ``(T,)``."""
    p = np.asarray(positions, np.float64)
    worst = np.full(len(p), -np.inf)
    for i in range(3):
        for k in range(3):
            dist = _segment_distance(
                p[:, int(_L[i])], p[:, int(_L[i + 1])], p[:, int(_R[k])], p[:, int(_R[k + 1])]
            )
            worst = np.maximum(worst, th.radius_m[i] + th.radius_m[k] - dist)
    return worst


def _bone_angles(local: F64) -> tuple[F64, F64]:
    """Angles (degrees) of a child bone that points down (-Y) at rest, under local
    rotations ``(T, 3, 3)``: its forward (+Z) angle in the sagittal plane, and its
    elevation out of that plane towards +X."""
    v = local[:, :, 1] * -1.0  # the rotated rest direction (0, -1, 0)
    sagittal = np.degrees(np.arctan2(v[:, 2], -v[:, 1]))
    return sagittal, np.degrees(np.arcsin(np.clip(v[:, 0], -1.0, 1.0)))


def joint_angles(world_mat: F64) -> dict[str, F64]:
    """Per frame and side, ``(T, 2)`` each (left, right), degrees:

    * ``knee_flex``: the shin's bend behind the thigh's axis (0 straight, + flexed,
      − hyperextended), from the knee's local rotation;
    * ``knee_side``: the shin's sideways bend in the thigh's frame (+ outward);
    * ``hip_flex``: the thigh forward of the pelvis's down axis (+ flexion,
      − extension);
    * ``hip_abd``: the thigh outward from it (+ abduction, − adduction).
    """
    local = np.asarray(local_rotations(np.asarray(world_mat, np.float64)), np.float64)
    out: dict[str, list[F64]] = {"knee_flex": [], "knee_side": [], "hip_flex": [], "hip_abd": []}
    for side, (thigh, shin) in enumerate(((_L[0], _L[1]), (_R[0], _R[1]))):
        outward = 1.0 if side == 0 else -1.0  # +X is the character's left
        fwd, lat = _bone_angles(local[:, int(shin)])  # the knee: shin in the thigh's frame
        out["knee_flex"].append(-fwd)  # flexion takes the shin backwards (-Z)
        out["knee_side"].append(lat * outward)
        fwd, lat = _bone_angles(local[:, int(thigh)])  # the hip: thigh in the pelvis's
        out["hip_flex"].append(fwd)
        out["hip_abd"].append(lat * outward)
    return {k: np.stack(v, axis=1) for k, v in out.items()}


def angle_violation(world_mat: F64, th: Thresholds = DEFAULT) -> B:
    """Frames with any joint angle outside the human range, ``(T,)``."""
    a = joint_angles(world_mat)
    bad = (a["knee_flex"] < th.knee_flex_deg[0]) | (a["knee_flex"] > th.knee_flex_deg[1])
    bad |= np.abs(a["knee_side"]) > th.knee_side_deg
    bad |= (a["hip_flex"] < th.hip_flex_deg[0]) | (a["hip_flex"] > th.hip_flex_deg[1])
    bad |= (a["hip_abd"] < th.hip_abd_deg[0]) | (a["hip_abd"] > th.hip_abd_deg[1])
    return np.asarray(bad.any(axis=1))


def floor_depth(positions: F64) -> F64:
    """How far the lowest foot or toe joint is below ``y = 0`` (metres, ``(T,)``)."""
    feet = [int(j) for j in (_L[2], _L[3], _R[2], _R[3])]
    return np.asarray(-np.asarray(positions, np.float64)[:, feet, 1].min(axis=1))


def toe_skate_speed(positions: F64, fps: float, th: Thresholds = DEFAULT) -> F64:
    """Per frame, the fastest horizontal speed (m/s) of a toe that is in contact by its
    own height (below ``contact_height_m`` at both ends of the step); 0 for the first
    frame and when no toe is down, ``(T,)``."""
    p = np.asarray(positions, np.float64)
    toes = p[:, [int(_L[3]), int(_R[3])]]  # (T, 2, 3)
    speed = toe_steps(p, fps)  # (T-1, 2)
    low = toes[:, :, 1] < th.contact_height_m
    down = low[1:] & low[:-1]
    out = np.zeros(len(p))
    out[1:] = np.where(down, speed, 0.0).max(axis=1)
    return out


def flags(world_mat: F64, positions: F64, fps: float, th: Thresholds = DEFAULT) -> dict[str, B]:
    """Per-frame flags of every category for one clip: ``{category: (T,) bool}``."""
    return {
        "self_intersection": leg_overlap(positions, th) > th.overlap_m,
        "joint_angle": angle_violation(world_mat, th),
        "floor": floor_depth(positions) > th.floor_m,
        "skate": toe_skate_speed(positions, fps, th) > th.skate_speed_m_s,
    }
