"""The knee and elbow hinges (:mod:`posecast.online.engine.hinge`): a knee or elbow bent
partly sideways is turned onto its hinge with no joint moving; a straight or
backward-bent one is left alone; the engine streams hinged knees and elbows on every
backend."""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from posecast.geometry.fk import fk_mat, world2local_mat
from posecast.geometry.rotations import aa2mat, mat2quat, quat2mat
from posecast.online.engine.hinge import (
    ELBOW_AXES,
    ELBOWS,
    KNEES,
    hinge_elbows,
    hinge_elbows_quat,
    hinge_knees,
    hinge_knees_quat,
)
from posecast.online.engine.types import TrackerFrame
from posecast.skeleton import NUM_JOINTS, Joint, reference_offsets
from tests.online.engine.conftest import BackendLoader, run_player

WalkFrames = Callable[..., list[TrackerFrame]]


def _knee_local(mat: np.ndarray) -> list[np.ndarray]:
    return [np.swapaxes(mat[:, t], -1, -2) @ mat[:, s] for t, s, _ in KNEES]


def _off_hinge_deg(local: np.ndarray) -> np.ndarray:
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
    before = [_off_hinge_deg(r) for r in _knee_local(mat)]
    assert min(before[0][0], before[1][0]) > 15.0
    feet = mat[:, [int(Joint.LEFT_FOOT), int(Joint.RIGHT_FOOT)]].copy()
    hinge_knees(mat, pos)
    after = [_off_hinge_deg(r) for r in _knee_local(mat)]
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


def test_the_engine_streams_hinged_knees(backend: BackendLoader, walk_frames: WalkFrames) -> None:
    """A walk, 4 points: every bent knee (over 15 degrees) streamed on its hinge within
    0.05 degrees (float32), the same joints as without the hinge; without it some knees
    are off their hinges by more than a degree."""
    frames = walk_frames(0)
    cfg = {"samples": 10, "lookahead": 2, "upper_body_ik": False}
    on = run_player(backend.engine(**cfg), frames)
    off = run_player(backend.engine(**cfg, knee_hinge=False), frames)
    pos_on = np.stack([p.positions for p in on])
    np.testing.assert_allclose(pos_on, np.stack([p.positions for p in off]), atol=1e-5)
    worst_on, worst_off = 0.0, 0.0
    for shown, pose_pos in ((on, pos_on), (off, None)):
        mat = quat2mat(np.stack([p.rotations for p in shown]).astype(np.float64))
        p = pos_on if pose_pos is None else pose_pos
        for (t, s, f), local in zip(KNEES, _knee_local(mat), strict=True):
            a, b = p[:, s] - p[:, t], p[:, f] - p[:, s]
            cos = np.sum(a * b, -1) / np.linalg.norm(a, axis=-1) / np.linalg.norm(b, axis=-1)
            bent = np.degrees(np.arccos(np.clip(cos, -1.0, 1.0))) > 15.0
            assert bent.sum() > 10
            worst = float(_off_hinge_deg(local)[bent].max())
            if shown is on:
                worst_on = max(worst_on, worst)
            else:
                worst_off = max(worst_off, worst)
    assert worst_on < 0.05
    assert worst_off > 1.0


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


def _off_elbow_hinge_deg(mat: np.ndarray) -> list[float]:
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
    assert min(_off_elbow_hinge_deg(mat)) > 20.0
    hands = mat[:, [int(Joint.LEFT_HAND), int(Joint.RIGHT_HAND)]].copy()
    hinge_elbows(mat, pos)
    assert max(_off_elbow_hinge_deg(mat)) < 1e-4
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


def test_the_engine_streams_hinged_elbows(backend: BackendLoader, walk_frames: WalkFrames) -> None:
    """A walk, 4 points: the streamed pose is the one without the elbow hinge with its
    elbows then put onto their hinges (the last pass), positions unchanged; and the
    hinge changed something."""
    frames = walk_frames(0)[:40]
    on, off = (
        run_player(backend.engine(samples=4, lookahead=2, elbow_hinge=e), frames)
        for e in (True, False)
    )
    pos = np.stack([p.positions for p in off])
    quat = np.stack([p.rotations for p in off])
    np.testing.assert_array_equal(np.stack([p.positions for p in on]), pos)
    hinged = quat.copy()
    hinge_elbows_quat(pos, hinged)
    got = np.stack([p.rotations for p in on])
    np.testing.assert_allclose(quat2mat(got), quat2mat(hinged), atol=1e-5)
    assert np.abs(quat2mat(got) - quat2mat(quat)).max() > 1e-2
