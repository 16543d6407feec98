"""Time resampling: frame-rate changes keep the duration, speed changes shorten it."""

from __future__ import annotations

import numpy as np
import pytest

from posecast.geometry.rotations import quat2mat, quat_slerp
from posecast.offline.motion.clip import CanonicalClip
from posecast.offline.motion.resample import resample
from posecast.offline.motion.synthetic import walk_clip


def duration_s(clip: CanonicalClip) -> float:
    """Time from the first frame to the last."""
    return (clip.n_frames - 1) / clip.fps


def test_same_rate_changes_nothing(walk: CanonicalClip) -> None:
    out = resample(walk, walk.fps)
    assert out.n_frames == walk.n_frames
    np.testing.assert_allclose(out.local_quat, walk.local_quat, atol=1e-12)
    np.testing.assert_allclose(out.root_pos, walk.root_pos, atol=1e-12)


@pytest.mark.parametrize("fps", [120.0, 60.0, 50.0, 30.0, 24.0])
def test_rate_change_keeps_duration(walk: CanonicalClip, fps: float) -> None:
    out = resample(walk, fps)
    assert out.fps == fps
    # Whole output frames only: at most one output frame short of the source.
    assert duration_s(walk) - 1.0 / fps < duration_s(out) <= duration_s(walk) + 1e-12
    # The metadata and the body stay.
    assert (out.name, out.subject, out.rig) == (walk.name, walk.subject, walk.rig)
    np.testing.assert_array_equal(out.offsets, walk.offsets)


def test_upsampling_interpolates_between_frames(walk: CanonicalClip) -> None:
    out = resample(walk, 2 * walk.fps)
    assert out.n_frames == 2 * walk.n_frames - 1
    np.testing.assert_allclose(out.local_quat[::2], walk.local_quat, atol=1e-12)
    np.testing.assert_allclose(out.root_pos[::2], walk.root_pos, atol=1e-12)
    # In between: the root halfway, each rotation slerped halfway.
    np.testing.assert_allclose(
        out.root_pos[1::2], 0.5 * (walk.root_pos[:-1] + walk.root_pos[1:]), atol=1e-12
    )
    mid = quat_slerp(walk.local_quat[:-1], walk.local_quat[1:], 0.5)
    np.testing.assert_allclose(quat2mat(out.local_quat[1::2]), quat2mat(mid), atol=1e-12)


def test_speed_two_halves_the_frames() -> None:
    clip = walk_clip(seconds=121 / 60, fps=60.0, seed=6)
    assert clip.n_frames == 121
    out = resample(clip, clip.fps, speed=2.0)
    assert out.n_frames == 61
    assert out.fps == clip.fps
    np.testing.assert_allclose(out.local_quat, clip.local_quat[::2], atol=1e-12)
    np.testing.assert_allclose(out.root_pos, clip.root_pos[::2], atol=1e-12)


def test_speed_perturbation_shortens_the_clip(walk: CanonicalClip) -> None:
    out = resample(walk, walk.fps, speed=1.1)
    want = duration_s(walk) / 1.1
    assert want - 1.0 / walk.fps < duration_s(out) <= want + 1e-12
    # Ten percent faster: the root covers its path in ten percent less time.
    np.testing.assert_allclose(out.root_pos[-1], walk.root_pos[-1], atol=0.02)


@pytest.mark.parametrize(("fps", "speed"), [(37.0, 1.0), (60.0, 0.9), (100.0, 1.3)])
def test_rotations_stay_unit(walk: CanonicalClip, fps: float, speed: float) -> None:
    out = resample(walk, fps, speed)
    np.testing.assert_allclose(np.linalg.norm(out.local_quat, axis=-1), 1.0, atol=1e-12)


@pytest.mark.parametrize(("fps", "speed"), [(0.0, 1.0), (-60.0, 1.0), (60.0, 0.0), (60.0, -1.0)])
def test_rejects_non_positive_rates(walk: CanonicalClip, fps: float, speed: float) -> None:
    with pytest.raises(ValueError, match="must be positive"):
        resample(walk, fps, speed)
