"""Swing clearance: a foot that moves over the floor is lifted off it.

The network's feet sit low: on the validation split most toes the plausibility check
flags as skating (``docs/evaluation.md``) are within a centimetre of the floor and
moving at 1-3 m/s, often while a drifted contact lock blends back to the network's
sliding ankle, where the true toe is 6-7 cm up, in its swing. Real feet keep a
clearance that grows with their horizontal speed: :data:`CLEARANCE_M` is the 5th
percentile of the ground-truth toe's height at each speed in :data:`SPEEDS_M_S`, on
the training split (``posecast data clearance``). The shown pose's toe is lifted to
that height for its speed, with the floor pass's two-bone solve (so a resting toe
sits at its resting height, 2 cm, and a sliding one steps over the floor instead).

The speed is the toe's horizontal speed between the previous shown frame and this one,
measured before any lift (lifting moves a foot straight up: the horizontal track is
the network's and the contact IK's), smoothed by an exponential average
(:data:`SPEED_SMOOTHING`) so the lift does not follow each frame's speed (the table
bins each step's own speed; the average lags it by about two frames), and started
again from rest where the whole body jumps (:data:`MAX_STEP_M_S`).
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from posecast.body.ik import FLOOR_MAX_LIFT_M, FLOOR_TOLERANCE_M, FLOOR_Y, LEGS
from posecast.skeleton import TOES as TOE_JOINTS

F64 = NDArray[np.floating]

TOES = [int(t) for t in TOE_JOINTS]
FEET = [int(leg[2]) for leg in LEGS]
# Speed bins (centres, m/s) and the toe's height (m above the floor) that 95 % of the
# training split's ground-truth toes keep at that speed, made non-decreasing; measured
# by `posecast data clearance --data prepared` (docs/evaluation.md, "Feet").
SPEEDS_M_S = (0.125, 0.375, 0.625, 0.875, 1.125, 1.375, 1.75, 2.25, 2.75, 3.5, 5.0)
CLEARANCE_M = (0.021, 0.022, 0.024, 0.028, 0.032, 0.037, 0.043, 0.05, 0.055, 0.055, 0.056)
# Weight of the previous frame's speed in the average (chosen on the validation split).
SPEED_SMOOTHING = 0.7
# A step faster than this (m/s; the table's last bin ends here, and no toe of the
# training split is faster) is a jump of the whole body, not a foot's motion: frames
# resuming after a gap, a new calibration scale, a recentred tracking space. The
# average starts again from rest there, instead of lifting both toes for a second.
MAX_STEP_M_S = 6.0


def toe_steps(positions: F64, fps: float) -> F64:
    """Both toes' horizontal speeds (m/s) from each frame of a clip ``(T, 19, 3)`` to the
    next, ``(T - 1, 2)``: the one measure the clearance, its table, the plausibility
    check's skate and the foot-skate metric share."""
    xz = np.asarray(positions, np.float64)[:, TOES][:, :, [0, 2]]
    out: F64 = np.linalg.norm(np.diff(xz, axis=0), axis=-1) * fps
    return out


def toe_speed(prev_xz: F64, toes_xz: F64, prev_speed: F64, fps: float) -> F64:
    """The averaged horizontal speed ``(B, 2)`` of both toes: ``toes_xz (B, 2, 2)`` now,
    ``prev_xz`` at the previous frame, ``prev_speed`` its average; 0 (at rest again)
    for a pose whose either toe stepped faster than :data:`MAX_STEP_M_S`."""
    raw = np.sqrt(np.sum((toes_xz - prev_xz) ** 2, axis=-1)) * fps
    jump = (raw > MAX_STEP_M_S).any(axis=-1, keepdims=True)
    out: F64 = np.where(jump, 0.0, SPEED_SMOOTHING * prev_speed + (1.0 - SPEED_SMOOTHING) * raw)
    return out


def clip_toe_speed(world_pos: F64, fps: float) -> F64:
    """:func:`toe_speed` over a clip ``(T, 19, 3)`` frame by frame, ``(T, 2)``: 0 on the
    first frame, as the engine starts a player."""
    xz = np.asarray(world_pos, np.float64)[:, TOES][:, :, [0, 2]]
    speed = np.zeros((len(xz), 2))
    for t in range(1, len(xz)):
        speed[t] = toe_speed(xz[t - 1 : t], xz[t : t + 1], speed[t - 1 : t], fps)[0]
    return speed


def clearance_lift(world_pos: F64, speed: F64, floor_y: float = FLOOR_Y) -> F64:
    """How far each foot ``(B, 2)`` must rise for its toe to clear the floor by the
    height real toes keep at ``speed (B, 2)``; 0 for a toe that does (within
    :data:`~posecast.body.ik.FLOOR_TOLERANCE_M`), and for a foot whose ankle
    or toe is more than :data:`~posecast.body.ik.FLOOR_MAX_LIFT_M` below the
    floor (a tracking space whose origin is not on the floor: the floor pass leaves
    those alone too)."""
    p = np.asarray(world_pos, np.float64)
    toe_y = p[:, TOES, 1]
    low = np.minimum(p[:, FEET, 1], toe_y)  # the floor pass's depth: the lower of the two
    lift = floor_y + np.interp(speed, SPEEDS_M_S, CLEARANCE_M) - toe_y
    out: F64 = np.where((lift > FLOOR_TOLERANCE_M) & (floor_y - low <= FLOOR_MAX_LIFT_M), lift, 0.0)
    return out
