"""The shown pelvis: where each decoded row's pelvis stands, and its smoothing over the look-ahead.

:func:`pelvis_poses` places the pelvis of decoded rows: the waist tracker's, or (a model
without one) the decoder's own guess, moved out of the head's frame. The engine places
its candidate pool's and its shown rows' with it, and the evaluation its clips'.

Every joint of the shown body hangs off the pelvis, so the pelvis's own frame-to-frame
noise (a waist tracker's, or the 3-point model's pelvis outputs) is carried out to the
feet and hands by the length of the limbs: the legs, which in the mocap stay planted
while the hips shake, shake with them. On the validation split that was most of the
excess jitter of the streamed pose (docs/evaluation.md, "Jitter"). The paper low-passes
the waist orientation for the same reason (Sec. 4.4); with the engine's look-ahead
(``tau`` frames; one is enough) the filter can be centred, so it adds no lag: the pose
shown for frame ``e`` is built on the pelvis averaged over frames ``e - 1``, ``e`` and
``e + 1`` with weights 1, 2, 1 (positions, and rotations as sign-aligned quaternions,
renormalised: :func:`smooth_pelvis`, the first pass of
:func:`posecast.body.pipeline.show`). The head and hands are then put on their
trackers as before.

Pure numpy.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
from numpy.typing import NDArray

from posecast.body.batch_fk import pelvis_from_head32
from posecast.geometry.rotations import mat2quat, quat2mat
from posecast.tracking.features import TrackerSlot

F32 = NDArray[np.float32]
F64 = NDArray[np.float64]
WEIGHTS = (0.25, 0.5, 0.25)  # frames e - 1, e, e + 1


class PelvisPoses(NamedTuple):
    """The world pelvis poses of ``R`` decoded rows, ``G`` of them, each shared by
    ``group = R / G`` consecutive rows: rotations ``mats (G, 3, 3)`` and positions
    ``places (G, 3)``, float32."""

    mats: F32
    places: F32
    group: int


def smooth_pelvis(
    mats: tuple[NDArray[np.floating], NDArray[np.floating], NDArray[np.floating]],
    places: tuple[NDArray[np.floating], NDArray[np.floating], NDArray[np.floating]],
) -> tuple[F64, F64]:
    """The 1-2-1 average of three pelvis poses: world rotations ``(..., 3, 3)`` and
    positions ``(..., 3)`` at frames ``e - 1``, ``e``, ``e + 1`` (a missing neighbour is
    passed as frame ``e`` again) -> the rotation and position shown at frame ``e``."""
    q = mat2quat(np.stack([np.asarray(m, np.float64) for m in mats]))  # (3, ..., 4)
    centre = q[1]
    w = np.asarray(WEIGHTS).reshape(3, *([1] * centre.ndim))
    sign = np.where(np.sum(q * centre, axis=-1, keepdims=True) < 0.0, -1.0, 1.0)
    acc = (w * sign * q).sum(axis=0)
    acc /= np.linalg.norm(acc, axis=-1, keepdims=True)
    pos = (w * np.stack([np.asarray(p, np.float64) for p in places])).sum(axis=0)
    return quat2mat(acc), np.asarray(pos, np.float64)


def smooth_pelvis_clip(mats: NDArray[np.floating], places: NDArray[np.floating]) -> tuple[F64, F64]:
    """:func:`smooth_pelvis` over a whole clip, ``(T, 3, 3)`` and ``(T, 3)``: the first
    and last frames stand in for their missing neighbour, as the engine's first frame."""
    m = np.asarray(mats, np.float64)
    p = np.asarray(places, np.float64)
    if len(m) < 2:
        return m.copy(), p.copy()
    prev_m, next_m = np.concatenate([m[:1], m[:-1]]), np.concatenate([m[1:], m[-1:]])
    prev_p, next_p = np.concatenate([p[:1], p[:-1]]), np.concatenate([p[1:], p[-1:]])
    return smooth_pelvis((prev_m, m, next_m), (prev_p, p, next_p))


def pelvis_poses(
    pos: F64,
    quat: F64,
    rootm: F32,
    root_out: F32 | None,
    repeat: int,
    waist: NDArray[np.bool_] | None = None,
) -> PelvisPoses:
    """The world pelvis poses of ``R = len(pos) * repeat`` decoded rows: rotations
    ``(G, 3, 3)`` and positions ``(G, 3)`` (float32), and how many rows share each, ``R / G``.

    ``pos (P, rows, 3)``, ``quat (P, rows, 4)``: the calibrated trackers of ``P``
    players. ``hmd3+waist``: the waist tracker's (``rootm``, its rotation ``(P, 3, 3)``
    float32), one per player (``G = P``), shared by its ``repeat`` rows. ``hmd3``: each
    row's own pelvis output ``root_out (R, 9)`` (6D rotation, position), moved out of
    the player's head frame into the world (``G = R``). ``sites``: as ``hmd3``, except
    that the rows of a player whose set tracks the waist's position (``waist``, per
    player) take the waist tracker's pose.
    """
    if root_out is None:
        return PelvisPoses(rootm, pos[:, TrackerSlot.WAIST].astype(np.float32), repeat)
    mats, places = pelvis_from_head32(root_out, pos[:, TrackerSlot.HEAD], quat[:, TrackerSlot.HEAD])
    if waist is not None and waist.any():
        rows = np.repeat(waist, repeat)
        players = np.flatnonzero(waist)
        wm = quat2mat(quat[players, TrackerSlot.WAIST]).astype(np.float32)
        mats[rows] = np.repeat(wm, repeat, axis=0)
        places[rows] = np.repeat(pos[players, TrackerSlot.WAIST].astype(np.float32), repeat, axis=0)
    return PelvisPoses(mats, places, 1)
