"""Per-frame arrays (posecast.offline.dataset.frames): what training reads."""

from __future__ import annotations

import numpy as np
import pytest

from posecast.geometry.rotations import quat2mat, r6d2mat
from posecast.offline.dataset.contacts import foot_contacts
from posecast.offline.dataset.frames import FIELDS, concat_frames, derive_frames
from posecast.offline.motion.synthetic import walk_clip
from posecast.skeleton import TOES
from posecast.tracking.features import TRACKER_JOINT_INDEX, clip_features, trackers_from_pose


@pytest.fixture(scope="module")
def clip():
    return walk_clip(seconds=1.5, fps=60.0, seed=4)


@pytest.fixture(scope="module")
def frames(clip):
    return derive_frames(clip)


def test_fields_have_the_documented_shapes_and_float32(clip, frames) -> None:
    assert set(frames) == set(FIELDS)
    for name, shape in FIELDS.items():
        assert frames[name].shape == (clip.n_frames, *shape), name
        assert frames[name].dtype == np.float32, name
        assert frames[name].flags.c_contiguous, name
        assert np.isfinite(frames[name]).all(), name
    assert FIELDS["rot6d"] == (18, 6)
    assert FIELDS["features"] == (24,)


def test_rot6d_reproduces_the_local_rotations(clip, frames) -> None:
    mats = r6d2mat(frames["rot6d"].astype(np.float64))
    np.testing.assert_allclose(mats, quat2mat(clip.local_quat[:, 1:]), atol=1e-5)
    # 6D is the first two columns, [c0, c1]
    want = quat2mat(clip.local_quat[:, 1:])
    np.testing.assert_allclose(frames["rot6d"][..., :3], want[..., :, 0], atol=1e-6)
    np.testing.assert_allclose(frames["rot6d"][..., 3:], want[..., :, 1], atol=1e-6)


def test_positions_are_the_clips_forward_kinematics(clip, frames) -> None:
    wm, wp = clip.fk()
    np.testing.assert_allclose(frames["positions"], wp, atol=1e-5)
    np.testing.assert_allclose(frames["root_pos"], clip.root_pos, atol=1e-5)
    np.testing.assert_allclose(frames["root_quat"], clip.local_quat[:, 0], atol=1e-6)
    t_pos, t_quat = trackers_from_pose(wm, wp)
    np.testing.assert_allclose(frames["tracker_pos"], wp[:, list(TRACKER_JOINT_INDEX)], atol=1e-5)
    np.testing.assert_allclose(frames["tracker_quat"], t_quat, atol=1e-6)
    np.testing.assert_allclose(frames["features"], clip_features(t_pos, t_quat, 60.0), atol=1e-5)


def test_contacts_are_the_toe_labels_as_zero_one(clip, frames) -> None:
    _, wp = clip.fk()
    want = foot_contacts(wp[:, list(TOES)], clip.fps)
    np.testing.assert_array_equal(frames["contacts"], want.astype(np.float32))
    assert 0 < frames["contacts"].mean() < 1  # a walk has both stance and swing


def test_concat_frames_records_where_each_clip_starts() -> None:
    parts = [
        derive_frames(walk_clip(seconds=s, fps=60.0, seed=i)) for i, s in enumerate((0.5, 1.0))
    ]
    parts.append(parts[0])
    joined, starts = concat_frames(parts)
    lengths = [len(p["features"]) for p in parts]
    assert lengths == [30, 60, 30]
    np.testing.assert_array_equal(starts, [0, 30, 90, 120])
    assert starts.dtype == np.int64
    for name in FIELDS:
        assert joined[name].shape[0] == 120
        for i, part in enumerate(parts):
            np.testing.assert_array_equal(joined[name][starts[i] : starts[i + 1]], part[name])


def test_concat_of_nothing_is_empty_with_the_right_shapes() -> None:
    joined, starts = concat_frames([])
    np.testing.assert_array_equal(starts, [0])
    for name, shape in FIELDS.items():
        assert joined[name].shape == (0, *shape)
        assert joined[name].dtype == np.float32
