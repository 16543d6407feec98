"""Rotation converters: round trips, edge cases, and the bone-alignment helpers."""

from __future__ import annotations

import numpy as np

from posecast_client.rotations import (
    euler2mat,
    kabsch,
    mat2euler_zyx,
    mat2quat,
    quat2mat,
    quat_mul,
    quat_nlerp,
    quat_normalize,
    vecs2mat,
)


def test_quat_mat_round_trip(rng: np.random.Generator) -> None:
    q = quat_normalize(rng.normal(size=(500, 4)))
    back = mat2quat(quat2mat(q))
    assert (back[:, 3] >= 0).all()
    np.testing.assert_allclose(np.abs((back * q).sum(-1)), 1.0, atol=1e-12)  # same up to sign
    m = quat2mat(q)
    np.testing.assert_allclose(m @ np.swapaxes(m, -1, -2), np.broadcast_to(np.eye(3), m.shape),
                               atol=1e-12)  # fmt: skip
    np.testing.assert_allclose(quat2mat(quat_mul(q[:-1], q[1:])), m[:-1] @ m[1:], atol=1e-12)


def test_euler_zyx_round_trip_and_gimbal_lock(rng: np.random.Generator) -> None:
    angles = rng.uniform([-np.pi, -1.5, -np.pi], [np.pi, 1.5, np.pi], (500, 3))
    np.testing.assert_allclose(mat2euler_zyx(euler2mat(angles, "ZYX")), angles, atol=1e-9)
    locked = euler2mat(np.array([0.3, np.pi / 2, -0.2]), "ZYX")
    np.testing.assert_allclose(euler2mat(mat2euler_zyx(locked), "ZYX"), locked, atol=1e-9)


def test_vecs2mat_turns_a_onto_b(rng: np.random.Generator) -> None:
    a, b = rng.normal(size=(200, 3)), rng.normal(size=(200, 3))
    turned = np.einsum("nab,nb->na", vecs2mat(a, b), a)
    unit = b / np.linalg.norm(b, axis=-1, keepdims=True)
    np.testing.assert_allclose(turned / np.linalg.norm(a, axis=-1, keepdims=True), unit, atol=1e-9)
    flip = vecs2mat(np.array([0.0, 1.0, 0.0]), np.array([0.0, -1.0, 0.0]))  # opposite
    np.testing.assert_allclose(flip @ [0.0, 1.0, 0.0], [0.0, -1.0, 0.0], atol=1e-12)


def test_kabsch_recovers_a_rotation_from_coplanar_bones(rng: np.random.Generator) -> None:
    rest = np.array([[0.0, 0.1, 0.0], [0.09, -0.05, 0.0], [-0.09, -0.05, 0.0]])  # the pelvis
    r = quat2mat(quat_normalize(rng.normal(size=(50, 4))))
    now = np.einsum("nab,kb->nka", r, rest)
    np.testing.assert_allclose(kabsch(np.broadcast_to(rest, now.shape), now), r, atol=1e-9)


def test_nlerp_takes_the_short_way() -> None:
    a = np.array([0.0, 0.0, 0.0, 1.0])
    b = -quat_normalize(np.array([0.0, 0.0, 0.1, 1.0]))  # the same small turn, other sign
    mid = quat_nlerp(a, b, 0.5)
    assert mid[3] > 0.99
