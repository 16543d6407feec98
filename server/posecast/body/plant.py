"""Planted toes: a toe the network says is in contact slides no faster than a bound.

Why (docs/latency.md, "Skating toes"): on the validation split most toes the
plausibility check flags as skating (85 % of 172 toe-frames, 4 points, streamed) are
in the display contact IK's release blend, two thirds of them a lock released because
the network's ankle drifted 5 cm from it while contact is still predicted
(:class:`~posecast.body.ik.ContactIK`): the shown foot then eases back onto the
network's ankle, which glides at 1.2-3 m/s where the true foot (70 % of them) is
planted. The swing clearance lifts a gliding toe only as far as its averaged speed
says, which lags a toe that speeds up, so such a toe slides 2.5-3 cm above the floor.

This pass follows the network's toe with an **offset** (per foot, horizontal): while
the foot is planted (predicted contact and the toe within :data:`LOW_M` of the floor)
the shown toe moves at most :data:`MAX_SPEED_M_S` from where it was shown the frame
before, and the offset takes up the rest of the network's glide, up to
:data:`MAX_LAG_M`; once the foot is not planted the offset shrinks at
:data:`CATCH_M_S`, so the toe returns onto the network's track without a jump. The
ankle is moved by the offset with the contact IK's two-bone solve (the foot keeps its
world rotation, so the toe moves with it). It runs after the contact IK and before
the legs are kept apart and the floor pass. A whole-body jump (a network toe step
faster than :data:`~posecast.body.clearance.MAX_STEP_M_S`) or a player's first frame
drops the offset. Pure numpy; the constants were chosen on the validation split.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from posecast.body.clearance import MAX_STEP_M_S, TOES
from posecast.body.ik import CONTACT_THRESHOLD, LEGS, THIGHS_SHINS, apply_leg_ik
from posecast.geometry.rotations import mat2quat, quat2mat

F32 = NDArray[np.float32]
F64 = NDArray[np.float64]

FEET = [int(leg[2]) for leg in LEGS]
MAX_SPEED_M_S = 1.0  # a planted toe's horizontal speed, at most (the check flags 1.2)
LOW_M = 0.03  # a toe below this (before the floor pass) can be planted
MAX_LAG_M = 0.04  # how far the shown toe may trail the network's
CATCH_M_S = 0.5  # how fast the trail is taken up once the foot is not planted


def plant_offsets(
    toes_xz: F64,
    toes_y: NDArray[np.floating],
    contacts: NDArray[np.floating],
    prev_xz: F64,
    offset: F64,
    first: NDArray[np.bool_],
    fps: float,
) -> F64:
    """The horizontal offsets ``(E, 2, 2)`` of both shown toes from the network's.

    ``toes_xz (E, 2, 2)`` / ``toes_y (E, 2)``: the network's (and contact IK's) toes now;
    ``contacts (E, 2)``: the predicted contact probabilities; ``prev_xz (E, 2, 2)``: the
    toes as shown the frame before, ``offset (E, 2, 2)`` their offsets then; ``first
    (E,)``: a player's first frame (no frame before it)."""
    off = np.where(first[:, None, None], 0.0, offset)
    before = prev_xz - off  # the network's toes the frame before
    jump = np.linalg.norm(toes_xz - before, axis=-1) * fps > MAX_STEP_M_S
    restart = (jump.any(axis=-1) | first)[:, None]  # (E, 1)
    planted = (contacts > CONTACT_THRESHOLD) & (toes_y < LOW_M)
    size = np.linalg.norm(off, axis=-1, keepdims=True)
    shrink = np.clip(1.0 - (CATCH_M_S / fps) / np.maximum(size, 1e-12), 0.0, 1.0)
    off = np.where(planted[..., None], off, off * shrink)
    want = toes_xz + off
    step = want - prev_xz
    dist = np.linalg.norm(step, axis=-1)
    cap = MAX_SPEED_M_S / fps
    slow = planted & ~restart & (dist > cap)
    shown = np.where(
        slow[..., None], prev_xz + step * (cap / np.maximum(dist, 1e-12))[..., None], want
    )
    off = np.where(restart[..., None], 0.0, shown - toes_xz)
    size = np.linalg.norm(off, axis=-1, keepdims=True)
    out: F64 = off * np.minimum(1.0, MAX_LAG_M / np.maximum(size, 1e-12))
    return out


def plant_toes(
    positions: F32,
    rotations: F32,
    contacts: NDArray[np.floating],
    prev_xz: F64,
    offset: F64,
    first: NDArray[np.bool_],
    fps: float,
) -> None:
    """Move the shown legs ``positions (E, 19, 3)``, ``rotations (E, 19, 4)`` xyzw
    (float32, in place: the thighs and shins turn) by :func:`plant_offsets`; ``prev_xz``
    and ``offset`` (the state, see there) move on to this frame."""
    xz = positions[:, TOES][:, :, [0, 2]].astype(np.float64)
    off = plant_offsets(xz, positions[:, TOES, 1], contacts, prev_xz, offset, first, fps)
    offset[...] = off
    prev_xz[...] = xz + off
    moved = np.linalg.norm(off, axis=-1) > 1e-6  # (E, 2)
    rows = np.flatnonzero(moved.any(axis=1))
    if not len(rows):
        return
    pos = positions[rows].astype(np.float64)
    mat = quat2mat(rotations[rows].astype(np.float64))
    targets = pos[:, FEET].copy()
    targets[..., [0, 2]] += off[rows]
    apply_leg_ik(mat, pos, targets, moved[rows])
    positions[rows] = pos
    rotations[np.ix_(rows, THIGHS_SHINS)] = mat2quat(mat[:, THIGHS_SHINS])
