"""The shown pose forecast a few frames ahead, from the poses shown before it.

A client that renders a pose some time after the server emitted it (its network and
render delay) may ask for poses predicted that far ahead (``forecast_ms``, 0 to
:data:`MAX_FORECAST_MS`). :func:`forecast` extrapolates a player's last shown poses:
every joint's world rotation turns on at its angular velocity over the last
``span`` frames, the pelvis moves on at its velocity (each frame's step ``damping``
times the one before; 1, undamped, was best on the validation split), and the other
joints are rebuilt from the pelvis with the shown pose's own bones (each bone's vector
in its parent's frame kept), so the bones keep their lengths and the positions stay FK
of the rotations. A pelvis that moved faster than
:data:`MAX_SPEED_M_S` (the whole body jumped: frames resuming after a gap, a new
calibration) is not extrapolated: that row is held. Pure numpy, no state; the engine
keeps the history (:meth:`posecast.online.engine.ssi.Engine.set_forecast`).

Chosen on the validation split, measured with ``posecast eval`` (docs/latency.md).
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from posecast.geometry.rotations import aa2quat, quat2aa, quat_apply, quat_conj, quat_mul
from posecast.skeleton import PARENTS

F64 = NDArray[np.float64]

# The furthest a client may ask to see ahead (milliseconds).
MAX_FORECAST_MS = 100.0
# Frames the velocities are measured over (the newest minus the one SPAN frames back).
SPAN = 2
# Each frame ahead moves this share of the frame before's step. Undamped was best at
# every horizon on the validation split (spans 1-3, damping 0.7-1; docs/latency.md).
DAMPING = 1.0
# A pelvis faster than this moved as a whole (a gap, a recalibration): held, not
# extrapolated (the swing clearance's bound for the same jumps).
MAX_SPEED_M_S = 6.0
# The joints below the pelvis and their parents, in joint order (a parent before its child).
_CHILD = np.array([j for j, p in enumerate(PARENTS) if p >= 0])
_PARENT = np.array([p for p in PARENTS if p >= 0])


def steps_ahead(frames: F64, damping: float) -> F64:
    """How many frames' worth of the current velocity ``frames`` frames ahead add up to
    when each frame's step is ``damping`` times the one before: ``sum_{i=1..h}
    damping**i`` (continuous in ``h``; ``h`` itself for ``damping = 1``)."""
    h = np.asarray(frames, np.float64)
    if damping == 1.0:
        return h
    return damping * (1.0 - damping**h) / (1.0 - damping)


def forecast(
    positions: F64,
    rotations: F64,
    frames: F64,
    fps: float | F64,
    span: int = SPAN,
    damping: float = DAMPING,
) -> tuple[F64, F64]:
    """The poses ``frames`` ahead of the newest of ``positions (E, K, 19, 3)`` and world
    ``rotations (E, K, 19, 4)`` (xyzw; ``K > span`` frames per row, the newest last;
    ``frames (E,)``, 0 for none; ``fps`` the frame rate, or ``(E,)`` one per row:
    what the speed bound reads the pelvis's step against). Returns positions
    ``(E, 19, 3)`` and rotations ``(E, 19, 4)``, float64."""
    pos = np.asarray(positions, np.float64)
    rot = np.asarray(rotations, np.float64)
    if pos.shape[1] <= span:
        raise ValueError(f"forecast needs more than {span} frames of history")
    p_now, q_now = pos[:, -1], rot[:, -1]
    root_step = (p_now[:, 0] - pos[:, -1 - span, 0]) / span  # (E, 3) per frame
    g = steps_ahead(np.asarray(frames, np.float64), damping)
    g = np.where(np.linalg.norm(root_step, axis=-1) * fps > MAX_SPEED_M_S, 0.0, g)
    # Each joint's world rotation, turned on at its angular velocity.
    turn = quat2aa(quat_mul(q_now, quat_conj(rot[:, -1 - span]))) / span  # (E, 19, 3)
    q_new = quat_mul(aa2quat(turn * g[:, None, None]), q_now)
    q_new /= np.linalg.norm(q_new, axis=-1, keepdims=True)
    # Each bone in its parent's frame, as shown now, carried by the parent's new rotation
    # (all bones in one pass), then chained from the pelvis (parents come first).
    bone = quat_apply(quat_conj(q_now[:, _PARENT]), p_now[:, _CHILD] - p_now[:, _PARENT])
    step = quat_apply(q_new[:, _PARENT], bone)  # (E, 18, 3)
    p_new = np.empty_like(p_now)
    p_new[:, 0] = p_now[:, 0] + root_step * g[:, None]
    for k, (j, parent) in enumerate(zip(_CHILD, _PARENT, strict=True)):
        p_new[:, j] = p_new[:, parent] + step[:, k]
    return p_new, q_new
