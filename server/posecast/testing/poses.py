"""Shown poses for tests and benchmarks that drive routing without an engine."""

from __future__ import annotations

from typing import Any

import numpy as np
from numpy.typing import NDArray

from posecast.online.protocol.messages import Pose
from posecast.online.protocol.pose_out import PoseOut
from posecast.online.protocol.records import PoseState
from posecast.skeleton import reference_offsets

REST = np.cumsum(reference_offsets(), axis=0)  # any body: the reference offsets chained
IDENTITY = np.tile([0.0, 0.0, 0.0, 1.0], (19, 1))


def pose_out(
    player: str,
    seq: int = 0,
    t: float = 1.0,
    positions: NDArray[Any] | None = None,
    rotations: NDArray[Any] | None = None,
    scale: float = 1.0,
    reach_limited: bool = False,
) -> PoseOut:
    """One pose as the engine thread makes it (a rest body with identity rotations
    unless given)."""
    pos = REST if positions is None else positions
    rot = IDENTITY if rotations is None else rotations
    states = PoseState.batch([player], [seq], t, pos[None], rot[None], [scale], [reach_limited])
    outs, refused = PoseOut.batch(states, pos[None], rot[None])
    if refused:
        raise ValueError(f"the wire cannot carry {player}'s pose")
    return outs[0]


def of_message(pose: Pose, scale: float = 1.0) -> PoseOut:
    """``pose`` (a v1 message with rotations) as the engine thread would have made it."""
    assert pose.rotations is not None
    return pose_out(pose.player, pose.seq, pose.t, pose.positions, pose.rotations, scale)
