"""Rotation converters: batched over any leading shape, checked by round trips."""

from __future__ import annotations

import itertools

import numpy as np
import pytest

from posecast.geometry.rotations import (
    aa2mat,
    aa2quat,
    axis_angle_mat,
    axis_mat,
    euler2mat,
    mat2aa,
    mat2euler,
    mat2quat,
    mat2r6d,
    normalize,
    quat2aa,
    quat2mat,
    quat2r6d,
    quat2yaw,
    quat_apply,
    quat_conj,
    quat_identity,
    quat_mul,
    quat_slerp,
    r6d2mat,
    r6d2quat,
    vecs2quat,
    yaw2quat,
)

SHAPES = [(), (5,), (3, 4)]
ORDERS = ["".join(p) for p in itertools.permutations("XYZ")]


def random_quat(rng: np.random.Generator, shape: tuple[int, ...]) -> np.ndarray:
    """Uniformly distributed unit quaternions (normalised 4D Gaussians)."""
    return normalize(rng.normal(size=(*shape, 4)))


def random_mat(rng: np.random.Generator, shape: tuple[int, ...]) -> np.ndarray:
    return quat2mat(random_quat(rng, shape))


def same_rotation(q: np.ndarray) -> np.ndarray:
    """``q`` with the sign fixed (``w >= 0``): q and -q are the same rotation."""
    return np.where(q[..., 3:] < 0, -q, q)


def assert_rotation_matrix(m: np.ndarray) -> None:
    eye = np.broadcast_to(np.eye(3), m.shape)
    np.testing.assert_allclose(m @ np.swapaxes(m, -1, -2), eye, atol=1e-12)
    np.testing.assert_allclose(np.linalg.det(m), 1.0, atol=1e-12)


def rodrigues(aa: np.ndarray) -> np.ndarray:
    """Reference axis-angle to matrix, written out for one vector."""
    angle = np.linalg.norm(aa)
    k = aa / angle
    K = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    return np.eye(3) + np.sin(angle) * K + (1 - np.cos(angle)) * K @ K


# --- quaternions and matrices -------------------------------------------------------


@pytest.mark.parametrize("shape", SHAPES)
def test_quat2mat_is_a_rotation(rng: np.random.Generator, shape: tuple[int, ...]) -> None:
    m = quat2mat(random_quat(rng, shape))
    assert m.shape == (*shape, 3, 3)
    assert_rotation_matrix(m)


@pytest.mark.parametrize("shape", SHAPES)
def test_quat_mat_round_trip(rng: np.random.Generator, shape: tuple[int, ...]) -> None:
    q = random_quat(rng, shape)
    back = mat2quat(quat2mat(q))
    assert back.shape == (*shape, 4)
    assert np.all(back[..., 3] >= 0.0)
    np.testing.assert_allclose(back, same_rotation(q), atol=1e-12)
    m = random_mat(rng, shape)
    np.testing.assert_allclose(quat2mat(mat2quat(m)), m, atol=1e-12)


@pytest.mark.parametrize(
    "aa",
    [
        [0.0, 0.0, 0.0],
        [np.pi, 0.0, 0.0],  # trace -1: each of Shepperd's branches in turn
        [0.0, np.pi, 0.0],
        [0.0, 0.0, np.pi],
        [3.0, 0.0, 0.1],
        [0.1, -3.0, 0.0],
        [0.0, 0.2, 3.1],
        [2.0, 2.0, -1.0],
    ],
)
def test_mat2quat_every_branch(aa: list[float]) -> None:
    m = rodrigues(np.array(aa)) if np.any(aa) else np.eye(3)
    q = mat2quat(m)
    assert q[3] >= 0.0
    np.testing.assert_allclose(np.linalg.norm(q), 1.0, atol=1e-12)
    np.testing.assert_allclose(quat2mat(q), m, atol=1e-12)


def test_quat2mat_known_value() -> None:
    """A quarter turn about +Y takes +Z to +X (xyzw, scalar last)."""
    q = np.array([0.0, np.sin(np.pi / 4), 0.0, np.cos(np.pi / 4)])
    np.testing.assert_allclose(quat2mat(q) @ [0.0, 0.0, 1.0], [1.0, 0.0, 0.0], atol=1e-15)


@pytest.mark.parametrize("shape", SHAPES)
def test_quat_mul_matches_matrix_product(rng: np.random.Generator, shape: tuple[int, ...]) -> None:
    a, b = random_quat(rng, shape), random_quat(rng, shape)
    np.testing.assert_allclose(quat2mat(quat_mul(a, b)), quat2mat(a) @ quat2mat(b), atol=1e-12)


def test_quat_mul_broadcasts(rng: np.random.Generator) -> None:
    a, b = random_quat(rng, (3, 1)), random_quat(rng, (4,))
    ab = quat_mul(a, b)
    assert ab.shape == (3, 4, 4)
    np.testing.assert_allclose(quat_mul(a[2, 0], b[1]), ab[2, 1], atol=1e-15)


@pytest.mark.parametrize("shape", SHAPES)
def test_quat_conj_inverts(rng: np.random.Generator, shape: tuple[int, ...]) -> None:
    q = random_quat(rng, shape)
    np.testing.assert_allclose(quat_mul(q, quat_conj(q)), quat_identity(shape), atol=1e-12)


@pytest.mark.parametrize("shape", SHAPES)
def test_quat_apply_matches_quat2mat(rng: np.random.Generator, shape: tuple[int, ...]) -> None:
    q = random_quat(rng, shape)
    v = rng.normal(size=(*shape, 3))
    expected = np.einsum("...ab,...b->...a", quat2mat(q), v)
    np.testing.assert_allclose(quat_apply(q, v), expected, atol=1e-12)


def test_converters_leave_their_input_alone(rng: np.random.Generator) -> None:
    q = random_quat(rng, (5,))
    m = quat2mat(q)
    q_before, m_before = q.copy(), m.copy()
    for convert in (quat_conj, quat2mat, quat2aa, quat2r6d, quat2yaw):
        convert(q)
    for convert in (mat2quat, mat2r6d, mat2aa):
        convert(m)
    mat2euler(m, "ZYX")
    np.testing.assert_array_equal(q, q_before)
    np.testing.assert_array_equal(m, m_before)


def test_normalize_keeps_zero_vectors_zero() -> None:
    out = normalize(np.array([[0.0, 0.0, 0.0], [3.0, 0.0, 4.0]]))
    np.testing.assert_array_equal(out, [[0.0, 0.0, 0.0], [0.6, 0.0, 0.8]])


# --- 6D -------------------------------------------------------------------------------


@pytest.mark.parametrize("shape", SHAPES)
def test_mat_r6d_round_trip(rng: np.random.Generator, shape: tuple[int, ...]) -> None:
    m = random_mat(rng, shape)
    d = mat2r6d(m)
    assert d.shape == (*shape, 6)
    np.testing.assert_allclose(r6d2mat(d), m, atol=1e-12)
    q = random_quat(rng, shape)
    np.testing.assert_allclose(r6d2quat(quat2r6d(q)), same_rotation(q), atol=1e-12)


@pytest.mark.parametrize("shape", SHAPES)
def test_any_6d_vector_is_a_rotation(rng: np.random.Generator, shape: tuple[int, ...]) -> None:
    """What a network outputs need not be orthonormal; Gram-Schmidt makes it so."""
    d = rng.normal(size=(*shape, 6)) * 3.0
    m = r6d2mat(d)
    assert_rotation_matrix(m)
    np.testing.assert_allclose(m[..., :, 0], normalize(d[..., :3]), atol=1e-12)
    # The second column stays in the plane of the two input vectors.
    normal = np.cross(d[..., :3], d[..., 3:])
    np.testing.assert_allclose(np.sum(m[..., :, 1] * normal, axis=-1), 0.0, atol=1e-12)


# --- axis-angle -----------------------------------------------------------------------


@pytest.mark.parametrize("shape", SHAPES)
def test_aa_quat_round_trip(rng: np.random.Generator, shape: tuple[int, ...]) -> None:
    # Angles below pi, where axis-angle is unique.
    axis = normalize(rng.normal(size=(*shape, 3)))
    aa = axis * rng.uniform(0.0, np.pi - 1e-3, size=(*shape, 1))
    np.testing.assert_allclose(quat2aa(aa2quat(aa)), aa, atol=1e-12)
    np.testing.assert_allclose(mat2aa(aa2mat(aa)), aa, atol=1e-9)
    m = random_mat(rng, shape)
    np.testing.assert_allclose(aa2mat(mat2aa(m)), m, atol=1e-12)


def test_aa2mat_matches_rodrigues(rng: np.random.Generator) -> None:
    for aa in rng.normal(size=(10, 3)):
        np.testing.assert_allclose(aa2mat(aa), rodrigues(aa), atol=1e-12)


@pytest.mark.parametrize("angle", [0.0, 1e-12, 1e-9, 1e-6])
def test_aa_near_zero_is_smooth(angle: float) -> None:
    aa = np.array([angle, -angle, 0.5 * angle])
    q = aa2quat(aa)
    assert np.all(np.isfinite(q))
    np.testing.assert_allclose(np.linalg.norm(q), 1.0, atol=1e-15)
    np.testing.assert_allclose(q[:3], 0.5 * aa, rtol=1e-9, atol=1e-300)
    np.testing.assert_allclose(quat2aa(q), aa, rtol=1e-9, atol=1e-300)


def test_quat2aa_takes_the_short_way() -> None:
    """-q is the same rotation as q; its axis-angle is the same vector."""
    aa = np.array([0.0, 0.0, 0.5])
    np.testing.assert_allclose(quat2aa(-aa2quat(aa)), aa, atol=1e-15)


# --- Euler angles -----------------------------------------------------------------------


@pytest.mark.parametrize("axis", ["X", "Y", "Z"])
def test_axis_mat_is_a_right_handed_turn(axis: str) -> None:
    aa = np.zeros(3)
    aa["XYZ".index(axis)] = 0.7
    np.testing.assert_allclose(axis_mat(axis, 0.7), rodrigues(aa), atol=1e-15)


def test_euler2mat_composes_in_channel_order() -> None:
    """``"ZYX"`` means ``Rz(a0) @ Ry(a1) @ Rx(a2)``, the BVH convention."""
    a = np.array([0.3, -0.2, 1.1])
    expected = axis_mat("Z", a[0]) @ axis_mat("Y", a[1]) @ axis_mat("X", a[2])
    np.testing.assert_allclose(euler2mat(a, "ZYX"), expected, atol=1e-15)
    # Any number of axes, as BVH channel lists allow.
    np.testing.assert_allclose(euler2mat([0.4], "Y"), axis_mat("Y", 0.4), atol=1e-15)
    np.testing.assert_allclose(euler2mat([0.1, 0.2], "XX"), axis_mat("X", 0.3), atol=1e-15)


@pytest.mark.parametrize("order", ORDERS)
@pytest.mark.parametrize("shape", SHAPES)
def test_mat_euler_round_trip(rng: np.random.Generator, order: str, shape: tuple[int, ...]) -> None:
    m = random_mat(rng, shape)
    e = mat2euler(m, order)
    assert e.shape == (*shape, 3)
    assert np.all(np.abs(e[..., 1]) <= np.pi / 2)
    np.testing.assert_allclose(euler2mat(e, order), m, atol=1e-12)
    # Angles inside the principal ranges come back as they were.
    angles = rng.uniform(-1.0, 1.0, size=(*shape, 3)) * [np.pi * 0.99, 1.5, np.pi * 0.99]
    np.testing.assert_allclose(mat2euler(euler2mat(angles, order), order), angles, atol=1e-9)


@pytest.mark.parametrize("order", ORDERS)
@pytest.mark.parametrize("distance", [0.0, 1e-12, 1e-9, 1e-7, 1e-5, 4e-5, 1e-3])
def test_mat_euler_near_gimbal_lock(rng: np.random.Generator, order: str, distance: float) -> None:
    """With the middle angle at or near +-90 degrees the matrix still comes back.

    The matrices go through a quaternion first, so their entries carry ordinary
    rounding error rather than the exact structure ``euler2mat`` gives them.
    """
    angles = rng.uniform(-np.pi, np.pi, size=(50, 3))
    angles[:, 1] = np.where(rng.random(50) < 0.5, 1.0, -1.0) * (np.pi / 2 - distance)
    m = quat2mat(mat2quat(euler2mat(angles, order)))
    e = mat2euler(m, order)
    assert np.all(np.isfinite(e))
    assert np.all(np.abs(e[:, 1]) <= np.pi / 2)
    np.testing.assert_allclose(euler2mat(e, order), m, atol=1e-6)


@pytest.mark.parametrize("order", ORDERS)
def test_mat2euler_at_exact_lock_puts_the_turn_in_the_first_angle(order: str) -> None:
    angles = np.array([0.4, np.pi / 2, 0.3])
    m = euler2mat(angles, order)
    e = mat2euler(m, order)
    assert e[2] == 0.0
    np.testing.assert_allclose(euler2mat(e, order), m, atol=1e-12)


def test_euler_rejects_bad_orders() -> None:
    with pytest.raises(ValueError, match="angles for order"):
        euler2mat([0.1, 0.2], "XYZ")
    for order in ("XYX", "XY", "XYW"):
        with pytest.raises(ValueError, match="three distinct axes"):
            mat2euler(np.eye(3), order)
    with pytest.raises(ValueError, match="unknown axis"):
        axis_mat("W", 0.1)


# --- slerp ------------------------------------------------------------------------------


@pytest.mark.parametrize("shape", SHAPES)
def test_slerp_endpoints_and_midpoint(rng: np.random.Generator, shape: tuple[int, ...]) -> None:
    q0 = random_quat(rng, shape)
    axis = normalize(rng.normal(size=(*shape, 3)))
    angle = rng.uniform(0.1, 3.0, size=(*shape, 1))
    q1 = quat_mul(aa2quat(axis * angle), q0)
    np.testing.assert_allclose(quat2mat(quat_slerp(q0, q1, 0.0)), quat2mat(q0), atol=1e-12)
    np.testing.assert_allclose(quat2mat(quat_slerp(q0, q1, 1.0)), quat2mat(q1), atol=1e-12)
    mid = quat_mul(aa2quat(axis * angle * 0.5), q0)
    np.testing.assert_allclose(
        same_rotation(quat_slerp(q0, q1, 0.5)), same_rotation(mid), atol=1e-12
    )


def test_slerp_turns_at_constant_speed_the_short_way() -> None:
    q0 = quat_identity()
    q1 = aa2quat([0.0, 2.0, 0.0])
    t = np.linspace(0.0, 1.0, 9)
    expected = aa2quat(np.outer(t, [0.0, 2.0, 0.0]))
    np.testing.assert_allclose(quat_slerp(q0, q1, t), expected, atol=1e-12)
    # -q1 is the same rotation: the path must not go the long way round.
    np.testing.assert_allclose(same_rotation(quat_slerp(q0, -q1, t)), expected, atol=1e-12)


def test_slerp_of_nearly_equal_rotations_is_finite() -> None:
    q0 = aa2quat([0.3, 0.0, 0.0])
    q1 = aa2quat([0.3 + 1e-9, 0.0, 0.0])
    out = quat_slerp(q0, q1, 0.5)
    assert np.all(np.isfinite(out))
    np.testing.assert_allclose(out, aa2quat([0.3 + 5e-10, 0.0, 0.0]), atol=1e-12)


# --- vecs2quat and yaw -------------------------------------------------------------------


@pytest.mark.parametrize("shape", SHAPES)
def test_vecs2quat_takes_a_onto_b(rng: np.random.Generator, shape: tuple[int, ...]) -> None:
    a = rng.normal(size=(*shape, 3))
    b = rng.normal(size=(*shape, 3)) * 5.0
    q = vecs2quat(a, b)
    np.testing.assert_allclose(quat_apply(q, normalize(a)), normalize(b), atol=1e-12)
    # The smallest such rotation: about a x b, by the angle between them.
    np.testing.assert_allclose(np.sum(q[..., :3] * a, axis=-1), 0.0, atol=1e-12)
    np.testing.assert_allclose(np.sum(q[..., :3] * b, axis=-1), 0.0, atol=1e-12)
    cos = np.sum(normalize(a) * normalize(b), axis=-1)
    np.testing.assert_allclose(np.linalg.norm(quat2aa(q), axis=-1), np.arccos(cos), atol=1e-7)


@pytest.mark.parametrize(
    "a", [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, -2.0], [0.3, -0.5, 0.8]]
)
def test_vecs2quat_opposite_vectors(a: list[float]) -> None:
    va = np.array(a)
    q = vecs2quat(va, -va)
    assert np.all(np.isfinite(q))
    np.testing.assert_allclose(np.linalg.norm(q), 1.0, atol=1e-12)
    np.testing.assert_allclose(quat_apply(q, normalize(va)), -normalize(va), atol=1e-12)


def test_vecs2quat_batch_mixing_opposite_and_ordinary_pairs() -> None:
    a = np.array([[0.0, 1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])
    b = np.array([[0.0, -1.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]])
    q = vecs2quat(a, b)
    np.testing.assert_allclose(quat_apply(q, a), b, atol=1e-12)
    np.testing.assert_allclose(q[2], quat_identity(), atol=1e-15)


def test_yaw_round_trip_and_heading() -> None:
    yaw = np.linspace(-3.0, 3.0, 13)
    q = yaw2quat(yaw)
    np.testing.assert_allclose(quat2yaw(q), yaw, atol=1e-12)
    fwd = quat_apply(q, np.array([0.0, 0.0, 1.0]))
    np.testing.assert_allclose(fwd, np.stack([np.sin(yaw), 0 * yaw, np.cos(yaw)], -1), atol=1e-12)
    # Looking up or down (a turn about the body's X axis) leaves the heading alone.
    pitched = quat_mul(q, aa2quat([0.6, 0.0, 0.0]))
    np.testing.assert_allclose(quat2yaw(pitched), yaw, atol=1e-12)


def test_axis_angle_mat_matches_aa2mat(rng: np.random.Generator) -> None:
    """Rodrigues on a unit axis gives :func:`aa2mat` of axis times angle, a zero angle
    the identity (any axis)."""
    axis = rng.normal(size=(64, 3))
    axis /= np.linalg.norm(axis, axis=-1, keepdims=True)
    angle = rng.uniform(-np.pi, np.pi, 64)
    angle[:4] = 0.0
    got = axis_angle_mat(axis, angle)
    np.testing.assert_allclose(got, aa2mat(axis * angle[:, None]), atol=1e-12)
    np.testing.assert_allclose(got[:4], np.broadcast_to(np.eye(3), (4, 3, 3)), atol=1e-15)
