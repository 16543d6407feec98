"""Numpy forward kinematics: rest pose, worked examples, and the inverse it has."""

from __future__ import annotations

import numpy as np
import pytest

from posecast.geometry.fk import fk_mat, fk_positions, world2local_mat
from posecast.geometry.rotations import aa2mat, normalize, quat2mat, yaw2quat
from posecast.skeleton import NUM_JOINTS, PARENTS, Joint, reference_offsets


def random_local(rng: np.random.Generator, shape: tuple[int, ...]) -> np.ndarray:
    """Random local rotations ``(*shape, 19, 3, 3)``."""
    return quat2mat(normalize(rng.normal(size=(*shape, NUM_JOINTS, 4))))


def identity(shape: tuple[int, ...] = ()) -> np.ndarray:
    return np.broadcast_to(np.eye(3), (*shape, NUM_JOINTS, 3, 3)).copy()


def test_rest_pose_cumulates_offsets() -> None:
    off = reference_offsets()
    root = np.array([0.5, 0.98, -2.0])
    mats, pos = fk_mat(identity(), root, off)
    np.testing.assert_array_equal(mats, identity())
    np.testing.assert_allclose(pos[Joint.PELVIS], root)
    head = root + off[[Joint.SPINE, Joint.CHEST, Joint.NECK, Joint.HEAD]].sum(axis=0)
    np.testing.assert_allclose(pos[Joint.HEAD], head)
    np.testing.assert_allclose(pos[Joint.HEAD], root + np.array([0.0, 0.62, 0.0]))
    np.testing.assert_allclose(pos[Joint.LEFT_HAND], root + np.array([0.70, 0.47, 0.0]))
    np.testing.assert_allclose(pos[Joint.RIGHT_TOE], root + np.array([-0.09, -0.96, 0.13]))


def test_root_rotation_turns_the_whole_body() -> None:
    """Yaw the root a quarter turn left: the figure faces +X, its left hand points -Z."""
    local = identity()
    local[Joint.PELVIS] = quat2mat(yaw2quat(np.pi / 2))
    mats, pos = fk_mat(local, np.zeros(3), reference_offsets())
    np.testing.assert_allclose(pos[Joint.LEFT_HAND], [0.0, 0.47, -0.70], atol=1e-12)
    np.testing.assert_allclose(pos[Joint.LEFT_TOE], [0.13, -0.96, -0.09], atol=1e-12)
    np.testing.assert_allclose(mats[Joint.HEAD], local[Joint.PELVIS], atol=1e-15)


def test_a_bent_elbow_moves_only_the_hand() -> None:
    """Three-joint arm along +X; a quarter turn about +Z at the elbow lifts the hand."""
    parents = (-1, 0, 1)
    offsets = np.array([[0.0, 0.0, 0.0], [0.3, 0.0, 0.0], [0.25, 0.0, 0.0]])
    local = np.broadcast_to(np.eye(3), (3, 3, 3)).copy()
    local[1] = aa2mat([0.0, 0.0, np.pi / 2])
    pos = fk_positions(local, [1.0, 2.0, 3.0], offsets, parents)
    np.testing.assert_allclose(pos, [[1.0, 2.0, 3.0], [1.3, 2.0, 3.0], [1.3, 2.25, 3.0]])


@pytest.mark.parametrize("shape", [(), (7,), (2, 3)])
def test_world2local_inverts_fk(rng: np.random.Generator, shape: tuple[int, ...]) -> None:
    local = random_local(rng, shape)
    world, pos = fk_mat(local, rng.normal(size=(*shape, 3)), reference_offsets())
    assert world.shape == (*shape, NUM_JOINTS, 3, 3)
    assert pos.shape == (*shape, NUM_JOINTS, 3)
    np.testing.assert_allclose(world2local_mat(world), local, atol=1e-12)


def test_fk_keeps_bone_lengths(rng: np.random.Generator) -> None:
    off = reference_offsets()
    pos = fk_positions(random_local(rng, (7,)), rng.normal(size=(7, 3)), off)
    for j, p in enumerate(PARENTS[1:], start=1):
        lengths = np.linalg.norm(pos[:, j] - pos[:, p], axis=-1)
        np.testing.assert_allclose(lengths, np.linalg.norm(off[j]), atol=1e-12)


def test_batched_equals_one_at_a_time(rng: np.random.Generator) -> None:
    """Per-sample offsets ``(B, J, 3)`` and a batch give what B single calls give."""
    local = random_local(rng, (4,))
    root = rng.normal(size=(4, 3))
    off = reference_offsets() * rng.uniform(0.8, 1.2, size=(4, 1, 1))
    _, batched = fk_mat(local, root, off)
    for b in range(4):
        np.testing.assert_allclose(batched[b], fk_positions(local[b], root[b], off[b]))


def test_fk_rejects_the_wrong_joint_count() -> None:
    with pytest.raises(ValueError, match="expected 19 joints"):
        fk_mat(np.broadcast_to(np.eye(3), (18, 3, 3)), np.zeros(3), reference_offsets()[:18])
