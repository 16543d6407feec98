"""The wire's position bounds (posecast.online.protocol.quantize.roots_on_wire)."""

from __future__ import annotations

import numpy as np

from posecast.online.protocol.messages import MAX_COORD_M
from posecast.online.protocol.quantize import roots_on_wire


def test_roots_past_the_wire_edge_move_the_pose_back_whole() -> None:
    rng = np.random.default_rng(3)
    poses = rng.normal(0.0, 0.5, (3, 19, 3))
    poses[1] += (1000.0, 0.0, -1000.0)
    poses[1, 0] = (1000.3, 1.0, -1000.2)  # a pelvis past two edges
    poses[2, :, 0] += np.nan  # refused later, by the encoder, not moved
    out = roots_on_wire(poses)
    np.testing.assert_array_equal(out[0], poses[0])
    np.testing.assert_array_equal(out[1, 0], (MAX_COORD_M, 1.0, -MAX_COORD_M))
    np.testing.assert_allclose(out[1] - out[1, 0], poses[1] - poses[1, 0])  # same shape
    np.testing.assert_array_equal(out[2], poses[2])


def test_poses_inside_are_returned_as_they_are() -> None:
    poses = np.zeros((2, 19, 3))
    poses[:, :, 0] = MAX_COORD_M  # on the edge is inside
    assert roots_on_wire(poses) is poses
