"""The knee and elbow hinges (:mod:`posecast.body.hinge`): a knee or elbow bent
partly sideways is turned onto its hinge with no joint moving; a straight or
backward-bent one is left alone. The engine streaming them:
``tests/online/engine/test_shown.py``."""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from posecast.body.hinge import (
    ELBOW_AXES,
    ELBOWS,
    KNEES,
    hinge_elbows,
    hinge_elbows_quat,
    hinge_knees,
    hinge_knees_quat,
)
from posecast.geometry.fk import fk_mat, world2local_mat
from posecast.geometry.rotations import aa2mat, mat2quat, quat2mat
from posecast.online.engine.types import TrackerFrame
from posecast.skeleton import NUM_JOINTS, Joint, reference_offsets

WalkFrames = Callable[..., list[TrackerFrame]]


def knee_local(mat: np.ndarray) -> list[np.ndarray]:
    return [np.swapaxes(mat[:, t], -1, -2) @ mat[:, s] for t, s, _ in KNEES]


def off_hinge_deg(local: np.ndarray) -> np.ndarray:
    """How far (degrees) each local knee rotation ``(B, 3, 3)`` is from the nearest
    rotation about the thigh's x axis."""
    q = mat2quat(local)
    twist = np.zeros_like(q)
    twist[:, 0], twist[:, 3] = q[:, 0], q[:, 3]
    twist /= np.linalg.norm(twist, axis=-1, keepdims=True)
    dot = np.abs(np.sum(q * twist, axis=-1))
    return np.degrees(2.0 * np.arccos(np.clip(dot, -1.0, 1.0)))


def _poses(knee_aa: list[tuple[float, float, float]]) -> tuple[np.ndarray, np.ndarray]:
    """World rotations and positions of poses whose knees have the local rotations
    ``knee_aa`` (axis-angle, both legs), the thighs swung and twisted a little."""
    B = len(knee_aa)
    local = np.broadcast_to(np.eye(3), (B, NUM_JOINTS, 3, 3)).copy()
    rng = np.random.default_rng(0)
    for t, s, _ in KNEES:
        local[:, t] = aa2mat(rng.normal(0.0, 0.3, (B, 3)))
        local[:, s] = aa2mat(np.asarray(knee_aa, np.float64))
    root = np.zeros((B, 3))
    root[:, 1] = 0.95
    mat, pos = fk_mat(local, root, reference_offsets())
    return mat, pos


def test_a_sideways_knee_goes_onto_its_hinge_and_nothing_moves() -> None:
    # 40 degrees of flexion (+x) with 20 of sideways bend (about z) and a 15-degree twist.
    mat, pos = _poses([(0.7, 0.26, 0.35), (1.2, -0.3, 0.0), (0.02, 0.01, 0.01)])
    before = [off_hinge_deg(r) for r in knee_local(mat)]
    assert min(before[0][0], before[1][0]) > 15.0
    feet = mat[:, [int(Joint.LEFT_FOOT), int(Joint.RIGHT_FOOT)]].copy()
    hinge_knees(mat, pos)
    after = [off_hinge_deg(r) for r in knee_local(mat)]
    for leg in after:
        assert leg[0] < 1e-4 and leg[1] < 1e-4  # bent knees: on the hinge
    np.testing.assert_allclose([before[0][2], before[1][2]], [after[0][2], after[1][2]])
    _, again = fk_mat(world2local_mat(mat), pos[:, 0], reference_offsets())
    np.testing.assert_allclose(again, pos, atol=1e-9)  # no joint moved
    np.testing.assert_allclose(mat[:, [int(Joint.LEFT_FOOT), int(Joint.RIGHT_FOOT)]], feet)


def test_a_knee_bent_backward_is_left_alone() -> None:
    mat, pos = _poses([(-0.8, 0.0, 0.2)])
    want = mat.copy()
    hinge_knees(mat, pos)
    np.testing.assert_allclose(mat, want, atol=1e-12)


def test_the_quaternion_form_is_the_matrix_form() -> None:
    mat, pos = _poses([(0.7, 0.26, 0.35), (1.0, 0.1, -0.2)])
    quat = mat2quat(mat).astype(np.float32)
    hinge_knees_quat(pos.astype(np.float32), quat)
    hinge_knees(mat, pos)
    np.testing.assert_allclose(quat2mat(quat.astype(np.float64)), mat, atol=1e-5)


# --- elbows ---------------------------------------------------------------------------


def _elbow_poses(bend_deg: float, off_deg: float) -> tuple[np.ndarray, np.ndarray]:
    """Poses whose elbows flex ``bend_deg`` about their hinge axis (``ELBOW_AXES``),
    then turn ``off_deg`` about the upper arm's bone (off the hinge), the upper arms
    swung a little; both arms."""
    local = np.broadcast_to(np.eye(3), (1, NUM_JOINTS, 3, 3)).copy()
    rng = np.random.default_rng(1)
    for (upper, fore, _), axis, bone in zip(
        ELBOWS, ELBOW_AXES, ([1.0, 0.0, 0.0], [-1.0, 0.0, 0.0]), strict=True
    ):
        local[:, upper] = aa2mat(rng.normal(0.0, 0.3, (1, 3)))
        hinged = aa2mat(axis[None] * np.radians(bend_deg))
        local[:, fore] = aa2mat(np.asarray(bone)[None] * np.radians(off_deg)) @ hinged
    root = np.array([[0.0, 0.95, 0.0]])
    mat, pos = fk_mat(local, root, reference_offsets())
    return mat, pos


def off_elbow_hinge_deg(mat: np.ndarray) -> list[float]:
    out = []
    for (upper, fore, _), axis in zip(ELBOWS, ELBOW_AXES, strict=True):
        q = mat2quat(np.swapaxes(mat[:, upper], -1, -2) @ mat[:, fore])[0]
        along = np.dot(q[:3], axis)
        twist = np.array([*(along * axis), q[3]])
        twist /= np.linalg.norm(twist)
        out.append(float(np.degrees(2.0 * np.arccos(min(1.0, abs(np.dot(q, twist)))))))
    return out


def test_an_elbow_off_its_hinge_goes_onto_it_and_nothing_moves() -> None:
    """An elbow flexed 70 degrees and turned 30 off its hinge: the upper arm turns about
    its bone, the elbow ends on its hinge, no joint moves, the hands keep their world
    rotations (the controllers')."""
    mat, pos = _elbow_poses(70.0, 30.0)
    assert min(off_elbow_hinge_deg(mat)) > 20.0
    hands = mat[:, [int(Joint.LEFT_HAND), int(Joint.RIGHT_HAND)]].copy()
    hinge_elbows(mat, pos)
    assert max(off_elbow_hinge_deg(mat)) < 1e-4
    _, again = fk_mat(world2local_mat(mat), pos[:, 0], reference_offsets())
    np.testing.assert_allclose(again, pos, atol=1e-9)
    np.testing.assert_allclose(mat[:, [int(Joint.LEFT_HAND), int(Joint.RIGHT_HAND)]], hands)
    quat = mat2quat(_elbow_poses(70.0, 30.0)[0]).astype(np.float32)
    hinge_elbows_quat(pos.astype(np.float32), quat)
    np.testing.assert_allclose(quat2mat(quat.astype(np.float64)), mat, atol=1e-5)


def test_a_hinged_or_straight_elbow_is_left_alone() -> None:
    for bend, off in ((60.0, 0.0), (2.0, 30.0)):
        mat, pos = _elbow_poses(bend, off)
        want = mat.copy()
        hinge_elbows(mat, pos)
        np.testing.assert_allclose(mat, want, atol=1e-9)
