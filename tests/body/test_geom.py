"""The passes' shared geometry (posecast.body.geom): the vector helpers against numpy's
own, the smallest rotation between two directions, angle wrapping, the subtrees, and
turning a joint as FK of the changed local rotation would place its subtree."""

from __future__ import annotations

import numpy as np

from posecast.body.geom import (
    BONE_M,
    DESCENDANTS,
    EPS,
    cross3,
    norm3,
    swing_mat,
    turn_joint,
    unit3,
    wrap_angle,
)
from posecast.geometry.fk import fk_mat
from posecast.geometry.rotations import aa2mat, axis_mat
from posecast.skeleton import NUM_JOINTS, PARENTS, Joint, reference_offsets


def test_vector_helpers_are_numpys_on_any_batch_shape() -> None:
    rng = np.random.default_rng(0)
    a, b = rng.normal(size=(2, 5, 3)), rng.normal(size=(2, 5, 3))
    np.testing.assert_allclose(norm3(a), np.linalg.norm(a, axis=-1))
    np.testing.assert_allclose(cross3(a, b), np.cross(a, b))
    d, n = unit3(a)
    np.testing.assert_allclose(n, np.linalg.norm(a, axis=-1))
    np.testing.assert_allclose(d, a / n[..., None])
    d0, n0 = unit3(np.zeros((1, 3)))
    np.testing.assert_array_equal(d0, np.zeros((1, 3)))  # a zero vector keeps direction 0
    assert n0[0] == 0.0 and EPS > 0


def test_the_swing_takes_one_direction_onto_the_other_by_the_smallest_turn() -> None:
    rng = np.random.default_rng(1)
    a, b = rng.normal(size=(50, 3)), rng.normal(size=(50, 3)) * 3.0
    R = swing_mat(a, b)
    ua, ub = unit3(a)[0], unit3(b)[0]
    np.testing.assert_allclose(np.einsum("nij,nj->ni", R, ua), ub, atol=1e-12)
    np.testing.assert_allclose(
        R @ np.swapaxes(R, -1, -2), np.broadcast_to(np.eye(3), R.shape), atol=1e-12
    )
    np.testing.assert_allclose(np.linalg.det(R), 1.0)
    axis = cross3(ua, ub)  # the smallest turn keeps the axis a x b fixed
    np.testing.assert_allclose(np.einsum("nij,nj->ni", R, axis), axis, atol=1e-12)
    same = swing_mat(np.array([[0.0, 1.0, 0.0]]), np.array([[0.0, 2.0, 0.0]]))
    np.testing.assert_allclose(same[0], np.eye(3), atol=1e-15)


def test_opposite_directions_turn_half_a_turn_about_a_perpendicular() -> None:
    for v in ([1.0, 0.0, 0.0], [0.0, 0.0, -2.0], [0.3, -0.4, 0.5]):
        a = np.array([v])
        R = swing_mat(a, -a)[0]
        np.testing.assert_allclose(R @ unit3(a)[0][0], -unit3(a)[0][0], atol=1e-12)
        np.testing.assert_allclose(np.linalg.det(R), 1.0)
        np.testing.assert_allclose(R @ R, np.eye(3), atol=1e-12)  # half a turn


def test_angles_wrap_into_minus_pi_to_pi() -> None:
    got = wrap_angle(np.array([0.0, np.pi, -np.pi, 3 * np.pi / 2, -7.0, 10.0]))
    np.testing.assert_allclose(
        got, [0.0, -np.pi, -np.pi, -np.pi / 2, 2 * np.pi - 7.0, 10.0 - 4 * np.pi]
    )
    assert np.all((got >= -np.pi) & (got < np.pi))


def test_bones_and_subtrees_follow_the_skeleton() -> None:
    np.testing.assert_allclose(BONE_M, np.linalg.norm(reference_offsets(), axis=-1))
    assert set(DESCENDANTS[Joint.PELVIS]) == set(range(1, NUM_JOINTS))
    for j in range(NUM_JOINTS):
        for d in DESCENDANTS[j]:
            p = PARENTS[d]
            assert p == j or p in DESCENDANTS[j]  # every descendant hangs off j's subtree
    leaves = [j for j in range(NUM_JOINTS) if j not in PARENTS]
    assert leaves and all(DESCENDANTS[j] == [] for j in leaves)


def test_turning_a_joint_is_fk_of_its_turned_local_rotation() -> None:
    """Turning the left thigh's world rotation by ``R`` about the hip moves its subtree
    exactly where FK puts it after the same change to the thigh's local rotation."""
    rng = np.random.default_rng(2)
    local = aa2mat(rng.normal(scale=0.4, size=(3, NUM_JOINTS, 3)))  # (3, 19, 3, 3)
    root = rng.normal(size=(3, 3))
    mat, pos = (np.array(a, np.float64) for a in fk_mat(local, root, reference_offsets()))
    j, parent = int(Joint.LEFT_THIGH), PARENTS[Joint.LEFT_THIGH]
    R = axis_mat("Y", np.array([0.3, -0.2, 1.1]))  # (3, 3, 3): a turn per row
    changed = local.copy()  # the same turn as a local one: parent^-1 R world_j
    changed[:, j] = np.swapaxes(mat[:, parent], -1, -2) @ R @ mat[:, j]
    want_m, want_p = fk_mat(changed, root, reference_offsets())
    untouched = [k for k in range(NUM_JOINTS) if k != j and k not in DESCENDANTS[j]]
    before = pos.copy()
    turn_joint(pos, mat, j, R)
    np.testing.assert_allclose(pos, want_p, atol=1e-12)
    np.testing.assert_allclose(mat, want_m, atol=1e-12)
    np.testing.assert_array_equal(pos[:, untouched], before[:, untouched])
    assert not np.allclose(pos[:, DESCENDANTS[j]], before[:, DESCENDANTS[j]])
