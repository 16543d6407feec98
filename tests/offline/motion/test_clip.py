"""A clip on the canonical skeleton (offline.motion.clip): its shapes are checked, its
length and its FK are what its arrays say, and a copy changes only what it is told."""

from __future__ import annotations

import numpy as np
import pytest

from posecast.geometry.fk import fk_mat
from posecast.geometry.rotations import quat2mat
from posecast.offline.motion.clip import CanonicalClip
from posecast.skeleton import NUM_JOINTS, PARENTS, reference_offsets


def _clip(frames: int = 6, fps: float = 30.0, seed: int = 0) -> CanonicalClip:
    rng = np.random.default_rng(seed)
    q = rng.normal(size=(frames, NUM_JOINTS, 4))
    q /= np.linalg.norm(q, axis=-1, keepdims=True)
    return CanonicalClip("05_02", "05", fps, q, rng.normal(size=(frames, 3)))


def test_length_in_frames_and_seconds() -> None:
    clip = _clip(frames=6, fps=30.0)
    assert clip.n_frames == 6 and clip.seconds == pytest.approx(0.2)
    np.testing.assert_array_equal(clip.offsets, reference_offsets())
    assert clip.rig == ""


@pytest.mark.parametrize(
    ("quat_shape", "pos_shape"),
    [((6, NUM_JOINTS - 1, 4), (6, 3)), ((6, NUM_JOINTS, 3), (6, 3)), ((6, NUM_JOINTS, 4), (5, 3))],
)
def test_bad_shapes_are_refused(quat_shape: tuple[int, ...], pos_shape: tuple[int, ...]) -> None:
    with pytest.raises(ValueError, match="bad clip shapes"):
        CanonicalClip("c", "s", 30.0, np.zeros(quat_shape), np.zeros(pos_shape))


def test_fk_is_the_skeletons_fk_on_the_clips_own_body() -> None:
    clip = _clip().with_(offsets=reference_offsets() * 1.1)
    wm, wp = clip.fk()
    assert wm.shape == (6, NUM_JOINTS, 3, 3) and wp.shape == (6, NUM_JOINTS, 3)
    want_m, want_p = fk_mat(quat2mat(clip.local_quat), clip.root_pos, reference_offsets() * 1.1)
    np.testing.assert_allclose(wm, want_m, atol=1e-12)
    np.testing.assert_allclose(wp, want_p, atol=1e-12)
    np.testing.assert_allclose(wp[:, 0], clip.root_pos, atol=1e-12)  # the root at its path
    bone = np.linalg.norm(wp[:, 1:] - wp[:, list(PARENTS[1:])], axis=-1)  # (F, 18)
    np.testing.assert_allclose(
        bone,
        np.broadcast_to(1.1 * np.linalg.norm(reference_offsets()[1:], axis=-1), bone.shape),
        atol=1e-9,
    )


def test_with_replaces_only_the_given_fields_and_keeps_the_checks() -> None:
    clip = _clip()
    faster = clip.with_(fps=60.0, name="05_02_fast")
    assert (faster.fps, faster.name, clip.fps, clip.name) == (60.0, "05_02_fast", 30.0, "05_02")
    assert faster.subject == clip.subject and faster.local_quat is clip.local_quat
    with pytest.raises(ValueError, match="bad clip shapes"):
        clip.with_(root_pos=np.zeros((2, 3)))
