"""How far real wrists bend: the statistic behind the engine's elbow hint
(:data:`posecast.body.upper_ik.WRIST_ELBOW_SHARE`).

The upper-body pass places an elbow partly where a straight wrist puts it behind the
controller: the forearm along the hand's rest direction turned by the hand's world
rotation. Per frame and hand, the angle between that direction and the true forearm
(elbow to hand) is the wrist's bend as the hint sees it; ``posecast data wrists --data
prepared --split val`` prints its distribution over a split's ground truth.
"""

from __future__ import annotations

from collections.abc import Iterable

import numpy as np
from numpy.typing import NDArray

from posecast.body.upper_ik import straight_forearms
from posecast.skeleton import Joint

F64 = NDArray[np.floating]

_FORE = [int(Joint.LEFT_FOREARM), int(Joint.RIGHT_FOREARM)]
_HAND = [int(Joint.LEFT_HAND), int(Joint.RIGHT_HAND)]


def wrist_bend_deg(world_mat: F64, world_pos: F64) -> F64:
    """Both wrists' bend, degrees ``(T, 2)``, of one clip (world rotations
    ``(T, 19, 3, 3)`` and positions ``(T, 19, 3)``): the angle between each forearm and
    the direction a straight wrist gives it from the hand's rotation."""
    straight = straight_forearms(np.asarray(world_mat)[:, _HAND])  # (T, 2, 3)
    pos = np.asarray(world_pos, np.float64)
    fore = pos[:, _HAND] - pos[:, _FORE]
    fore /= np.maximum(np.linalg.norm(fore, axis=-1, keepdims=True), 1e-12)
    cos = np.clip(np.einsum("tki,tki->tk", fore, straight), -1.0, 1.0)
    out: F64 = np.degrees(np.arccos(cos))
    return out


def bend_summary(clips: Iterable[tuple[F64, F64]]) -> dict[str, float]:
    """Mean, median, 90th and 99th percentile of :func:`wrist_bend_deg` over ``clips``
    (``(world_mat, world_pos)`` each) and the number of hand-frames."""
    bends = [wrist_bend_deg(m, p).ravel() for m, p in clips]
    b = np.concatenate(bends) if bends else np.zeros(0)
    if not b.size:
        return {"hand_frames": 0.0}
    return {
        "hand_frames": float(b.size),
        "mean_deg": float(b.mean()),
        "median_deg": float(np.median(b)),
        "p90_deg": float(np.percentile(b, 90)),
        "p99_deg": float(np.percentile(b, 99)),
    }
