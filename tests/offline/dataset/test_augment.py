"""Augmentations (posecast.offline.dataset.augment): mirror, speed, bone lengths."""

from __future__ import annotations

import numpy as np
import pytest

from posecast.offline.dataset.augment import Augmentation, change_speed, mirror, scale_bones
from posecast.offline.dataset.frames import derive_frames
from posecast.offline.motion.synthetic import walk_clip
from posecast.skeleton import MIRROR_INDEX, PARENT, REST_TOE_HEIGHT_M, TOES, Joint

REFLECT_X = np.diag([-1.0, 1.0, 1.0])


@pytest.fixture(scope="module")
def clip():
    return walk_clip(seconds=2.0, fps=60.0, seed=2)


def test_mirror_twice_is_identity(clip) -> None:
    twice = mirror(mirror(clip))
    np.testing.assert_allclose(twice.local_quat, clip.local_quat, atol=0)
    np.testing.assert_allclose(twice.root_pos, clip.root_pos, atol=0)
    np.testing.assert_allclose(twice.offsets, clip.offsets, atol=0)
    assert not np.allclose(mirror(clip).local_quat, clip.local_quat)


def test_mirrored_left_hand_is_the_right_hand_reflected(clip) -> None:
    wm, wp = clip.fk()
    mm, mp = mirror(clip).fk()
    expected = wp[:, Joint.RIGHT_HAND] * [-1.0, 1.0, 1.0]
    np.testing.assert_allclose(mp[:, Joint.LEFT_HAND], expected, atol=1e-9)
    # and every joint, positions and orientations: p' = M p[mirror], R' = M R[mirror] M
    idx = list(MIRROR_INDEX)
    np.testing.assert_allclose(mp, wp[:, idx] @ REFLECT_X, atol=1e-9)
    np.testing.assert_allclose(mm, REFLECT_X @ wm[:, idx] @ REFLECT_X, atol=1e-9)
    assert np.abs(wp[:, Joint.LEFT_HAND] - wp[:, Joint.RIGHT_HAND] * [-1, 1, 1]).max() > 0.05


def test_mirror_swaps_contact_labels(clip) -> None:
    a = derive_frames(clip)["contacts"]
    b = derive_frames(mirror(clip))["contacts"]
    assert not np.array_equal(a[:, 0], a[:, 1])  # the swap is visible
    np.testing.assert_array_equal(b, a[:, ::-1])


def test_mirror_marks_the_name(clip) -> None:
    assert mirror(clip).name == clip.name + "~m"


def test_change_speed_two_halves_the_frames(clip) -> None:
    fast = change_speed(clip, 2.0)
    assert fast.fps == clip.fps
    assert fast.n_frames == (clip.n_frames - 1) // 2 + 1
    # Output frame k is source frame 2k exactly.
    np.testing.assert_allclose(fast.root_pos, clip.root_pos[::2], atol=1e-12)
    np.testing.assert_allclose(fast.local_quat, clip.local_quat[::2], atol=1e-9)


def test_change_speed_half_doubles_the_frames_and_keeps_the_path(clip) -> None:
    slow = change_speed(clip, 0.5)
    assert slow.n_frames == 2 * (clip.n_frames - 1) + 1
    np.testing.assert_allclose(slow.root_pos[::2], clip.root_pos, atol=1e-12)
    # the in-between frames lie half-way
    mid = 0.5 * (clip.root_pos[:-1] + clip.root_pos[1:])
    np.testing.assert_allclose(slow.root_pos[1::2], mid, atol=1e-12)


def test_change_speed_one_is_the_same_clip(clip) -> None:
    assert change_speed(clip, 1.0) is clip


@pytest.mark.parametrize("seed", range(4))
def test_scale_bones_keeps_the_body_symmetric_and_on_the_floor(clip, seed: int) -> None:
    aug = Augmentation(bone_scale=(0.85, 1.15), bone_jitter=0.1)
    scaled = scale_bones(clip, np.random.default_rng(seed), aug)
    off = scaled.offsets
    assert not np.allclose(off, clip.offsets)
    for j in Joint:
        if j.name.startswith("LEFT_"):
            right = Joint["RIGHT_" + j.name[5:]]
            np.testing.assert_allclose(off[right], off[j] * [-1.0, 1.0, 1.0], atol=1e-12)
    # Bone directions are unchanged, only lengths.
    for j in Joint:
        if PARENT[j] is not None:
            a, b = off[j], clip.offsets[j]
            cos = a @ b / np.linalg.norm(a) / np.linalg.norm(b)
            assert cos == pytest.approx(1.0)
    _, pos = scaled.fk()
    lower_toe = pos[:, list(TOES), 1].min(axis=1)
    assert abs(np.percentile(lower_toe, 5) - REST_TOE_HEIGHT_M) < 0.015
    assert lower_toe.min() > -0.01


def test_scale_bones_is_seeded(clip) -> None:
    aug = Augmentation(bone_scale=(0.9, 1.1), bone_jitter=0.05)
    a = scale_bones(clip, np.random.default_rng(7), aug)
    b = scale_bones(clip, np.random.default_rng(7), aug)
    c = scale_bones(clip, np.random.default_rng(8), aug)
    np.testing.assert_array_equal(a.offsets, b.offsets)
    assert not np.array_equal(a.offsets, c.offsets)


def test_augmentation_none_switches_everything_off(clip) -> None:
    none = Augmentation.none()
    assert none.mirror is False
    assert none.speeds == (1.0,)
    assert none.bone_scale == (1.0, 1.0)
    assert none.bone_jitter == 0.0
    assert scale_bones(clip, np.random.default_rng(0), none) is clip
    assert Augmentation().mirror is True  # the default does mirror
