"""The shown pose's forecast (body/forecast.py): steady motion extrapolated, bones kept."""

from __future__ import annotations

import numpy as np
import pytest

from posecast.body.forecast import MAX_SPEED_M_S, SPAN, forecast, steps_ahead
from posecast.geometry.rotations import aa2quat, quat2mat, quat_mul
from posecast.skeleton import PARENTS, reference_offsets

FPS = 60.0


def _steady(frames: int, v: np.ndarray, w: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """A body whose pelvis moves at ``v`` m/frame and every joint's world rotation
    turns at ``w`` rad/frame (about a fixed axis, on its own start pose): positions
    ``(frames, 19, 3)`` and world rotations ``(frames, 19, 4)``, FK of the rest bones."""
    rng = np.random.default_rng(0)
    start = aa2quat(rng.normal(0.0, 0.4, (19, 3)))
    offsets = reference_offsets()
    pos, rot = [], []
    for t in range(frames):
        q = quat_mul(aa2quat(np.broadcast_to(w * t, (19, 3))), start)
        mats = quat2mat(q)
        p = np.zeros((19, 3))
        p[0] = np.array([0.1, 1.0, -0.2]) + v * t
        for j, parent in enumerate(PARENTS):
            if parent >= 0:
                p[j] = p[parent] + mats[parent] @ offsets[j]
        pos.append(p)
        rot.append(q)
    return np.array(pos), np.array(rot)


def test_steady_motion_is_extrapolated_exactly_without_damping() -> None:
    v, w = np.array([0.01, 0.0, 0.02]), np.array([0.0, 0.03, 0.01])
    pos, rot = _steady(SPAN + 1 + 4, v, w)
    hist = slice(0, SPAN + 1)
    p, q = forecast(pos[None, hist], rot[None, hist], np.array([4.0]), FPS, damping=1.0)
    np.testing.assert_allclose(p[0], pos[SPAN + 4], atol=1e-9)
    np.testing.assert_allclose(np.abs(np.sum(q[0] * rot[SPAN + 4], -1)), 1.0, atol=1e-9)


def test_damping_goes_part_of_the_way_and_zero_frames_hold() -> None:
    v, w = np.array([0.02, 0.0, 0.0]), np.zeros(3)
    pos, rot = _steady(SPAN + 1, v, w)
    p, _ = forecast(
        np.stack([pos, pos]), np.stack([rot, rot]), np.array([4.0, 0.0]), FPS, damping=0.9
    )
    moved = p[0, 0, 0] - pos[-1, 0, 0]
    assert moved == pytest.approx(0.02 * (0.9 + 0.81 + 0.729 + 0.6561))
    assert steps_ahead(np.array([4.0]), 0.9)[0] == pytest.approx(0.9 + 0.81 + 0.729 + 0.6561)
    np.testing.assert_allclose(p[1], pos[-1], atol=1e-12)  # 0 frames ahead: the pose itself


def test_bones_keep_their_lengths_and_positions_stay_fk_of_the_rotations() -> None:
    rng = np.random.default_rng(3)
    pos, rot = _steady(SPAN + 1, np.array([0.0, 0.01, 0.0]), np.array([0.05, -0.02, 0.04]))
    rot[:-1] = quat_mul(aa2quat(rng.normal(0, 0.05, (SPAN, 19, 3))), rot[:-1])  # noisy turns
    p, q = forecast(pos[None], rot[None], np.array([6.0]), FPS)
    mats = quat2mat(q[0])
    for j, parent in enumerate(PARENTS):
        if parent >= 0:
            bone_now = np.linalg.norm(pos[-1, j] - pos[-1, parent])
            assert np.linalg.norm(p[0, j] - p[0, parent]) == pytest.approx(bone_now)
    # FK of the forecast's world rotations with the rest bones gives its positions.
    offsets = reference_offsets()
    fk = p[0].copy()
    for j, parent in enumerate(PARENTS):
        if parent >= 0:
            fk[j] = fk[parent] + mats[parent] @ offsets[j]
    np.testing.assert_allclose(fk, p[0], atol=1e-9)
    assert np.allclose(np.linalg.norm(q, axis=-1), 1.0)


def test_a_jump_of_the_whole_body_is_held() -> None:
    step = 1.5 * MAX_SPEED_M_S / FPS
    pos, rot = _steady(SPAN + 1, np.array([step, 0.0, 0.0]), np.array([0.0, 0.1, 0.0]))
    p, q = forecast(pos[None], rot[None], np.array([4.0]), FPS)
    np.testing.assert_allclose(p[0], pos[-1], atol=1e-12)
    np.testing.assert_allclose(q[0], rot[-1], atol=1e-12)


def test_too_short_a_history_is_refused() -> None:
    pos, rot = _steady(SPAN, np.zeros(3), np.zeros(3))
    with pytest.raises(ValueError, match="history"):
        forecast(pos[None], rot[None], np.array([1.0]), FPS)
