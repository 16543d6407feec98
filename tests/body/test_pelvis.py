"""The shown pelvis's 1-2-1 smoothing (:mod:`posecast.body.pelvis`): uniform
motion kept, a frame-to-frame shake taken out. The engine streaming it:
``tests/online/engine/test_shown.py``."""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from posecast.body.pelvis import smooth_pelvis, smooth_pelvis_clip
from posecast.geometry.rotations import aa2mat, mat2quat, quat2mat
from posecast.online.engine.types import TrackerFrame

WalkFrames = Callable[..., list[TrackerFrame]]


def _turning(n: int, rate: float, axis: tuple[float, float, float]) -> np.ndarray:
    """Rotations ``(n, 3, 3)`` about ``axis`` at ``rate`` radians a frame."""
    a = np.asarray(axis, np.float64) / np.linalg.norm(axis)
    return aa2mat(np.arange(n)[:, None] * rate * a)


def test_uniform_motion_is_kept_and_the_centre_alone_is_the_centre() -> None:
    n = 12
    mats = _turning(n, 0.05, (0.3, 1.0, -0.2))
    places = np.arange(n)[:, None] * np.array([0.01, 0.0, -0.02]) + [0.0, 0.95, 0.0]
    m, p = smooth_pelvis((mats[:-2], mats[1:-1], mats[2:]), (places[:-2], places[1:-1], places[2:]))
    np.testing.assert_allclose(m, mats[1:-1], atol=1e-12)
    np.testing.assert_allclose(p, places[1:-1], atol=1e-12)
    # Neighbours equal to the centre (a player's first frame stands in for its missing one).
    m, p = smooth_pelvis((mats, mats, mats), (places, places, places))
    np.testing.assert_allclose(m, mats, atol=1e-12)
    np.testing.assert_allclose(p, places, atol=1e-12)


def test_a_frame_to_frame_shake_is_taken_out() -> None:
    """A pelvis turning steadily with +-2 degrees of alternating shake on top (and +-5 mm
    of position): the 1-2-1 average is the steady motion again, within 0.2 degrees; the
    sign of a quaternion does not matter."""
    n = 40
    steady = _turning(n, 0.02, (0.0, 1.0, 0.0))
    shake = np.where(np.arange(n) % 2 == 0, 1.0, -1.0)
    noisy = aa2mat(shake[:, None] * np.radians(2.0) * np.array([1.0, 0.0, 0.0])) @ steady
    q = mat2quat(noisy)
    q[::3] *= -1.0  # the same rotations, other signs
    places = np.array([0.0, 0.95, 0.0]) + shake[:, None] * np.array([0.005, 0.0, 0.0])
    m, p = smooth_pelvis_clip(quat2mat(q), places)
    inner = slice(1, n - 1)
    cos = (np.einsum("tij,tij->t", m[inner], steady[inner]) - 1.0) / 2.0
    assert np.degrees(np.arccos(np.clip(cos, -1.0, 1.0))).max() < 0.2
    still = np.broadcast_to([0.0, 0.95, 0.0], p[inner].shape)
    np.testing.assert_allclose(p[inner], still, atol=1e-12)
    raw_cos = (np.einsum("tij,tij->t", noisy[inner], steady[inner]) - 1.0) / 2.0
    assert np.degrees(np.arccos(np.clip(raw_cos, -1.0, 1.0))).min() > 1.9  # the shake was there
