"""Tracker layouts: the headset-only features and the pelvis decoding they pair with."""

from __future__ import annotations

import numpy as np
import pytest

from posecast.geometry.rotations import mat2r6d, quat2mat, quat_apply, quat_mul, yaw2quat
from posecast.offline.dataset.frames import derive_frames
from posecast.offline.motion.synthetic import walk_clip
from posecast.skeleton import Joint
from posecast.tracking.features import FEATURE_NAMES_HMD3, TrackerSlot, character_frame
from posecast.tracking.layouts import Layout, pelvis_from_head, spec


@pytest.fixture(scope="module")
def walk() -> dict[str, np.ndarray]:
    fr = derive_frames(walk_clip(seconds=1.0, fps=60.0, seed=3))
    return {k: v.astype(np.float64) for k, v in fr.items()}


def test_specs_match_their_feature_functions(walk: dict[str, np.ndarray]) -> None:
    for layout, width in ((Layout.HMD3_WAIST, 24), (Layout.HMD3, 36)):
        ls = spec(layout)
        feats = ls.clip_features(walk["tracker_pos"], walk["tracker_quat"], 60.0)
        assert feats.shape == (len(walk["tracker_pos"]), width) == (feats.shape[0], ls.n_features)
    # The 4-point spec reproduces the features prepare stored.
    four = spec("hmd3+waist").clip_features(walk["tracker_pos"], walk["tracker_quat"], 60.0)
    np.testing.assert_allclose(four, walk["features"], atol=1e-4)
    assert spec("hmd3").predicts_root and not spec("hmd3+waist").predicts_root
    assert FEATURE_NAMES_HMD3[:3] == ("HEAD.px", "HEAD.py", "HEAD.pz")
    with pytest.raises(ValueError):
        spec("hmd2")


def test_hmd3_features_ignore_the_waist_and_where_the_player_stands(
    walk: dict[str, np.ndarray],
) -> None:
    """Turning and moving the whole scene about +Y changes no feature; the waist slot
    is not read at all; the first frame's velocity is zero."""
    ls = spec(Layout.HMD3)
    pos, quat = walk["tracker_pos"], walk["tracker_quat"]
    base = ls.clip_features(pos, quat, 60.0)
    turn = yaw2quat(0.9)
    moved = quat_apply(turn, pos) + np.array([2.0, 0.0, -1.5])
    turned = quat_mul(turn, quat)
    np.testing.assert_allclose(ls.clip_features(moved, turned, 60.0), base, atol=1e-6)
    garbage_waist = pos.copy()
    garbage_waist[:, TrackerSlot.WAIST] = 1e6
    np.testing.assert_array_equal(ls.clip_features(garbage_waist, quat, 60.0), base)
    velocity_cols = [i for i, n in enumerate(FEATURE_NAMES_HMD3) if ".v" in n]
    assert np.all(base[0, velocity_cols] == 0.0) and np.abs(base[1:, velocity_cols]).max() > 0.1


def test_pelvis_from_head_inverts_the_head_frame(walk: dict[str, np.ndarray]) -> None:
    """Encode the true pelvis in the head's yaw frame the way training targets are
    built, decode it with :func:`pelvis_from_head`: the world pelvis comes back."""
    head_pos = walk["tracker_pos"][:, TrackerSlot.HEAD]
    head_quat = walk["tracker_quat"][:, TrackerSlot.HEAD]
    pelvis = walk["positions"][:, Joint.PELVIS]
    origin, inv_yaw = character_frame(head_pos, head_quat)
    local_pos = quat_apply(inv_yaw, pelvis - origin)
    local_rot = quat2mat(quat_mul(inv_yaw, walk["root_quat"]))
    out = np.concatenate([mat2r6d(local_rot), local_pos], axis=-1)
    mats, places = pelvis_from_head(out, head_pos, head_quat)
    np.testing.assert_allclose(places, pelvis, atol=1e-9)
    np.testing.assert_allclose(mats, quat2mat(walk["root_quat"]), atol=1e-9)
    # The pelvis sits below the head and behind or under it: the frame is the head's.
    assert np.all(local_pos[:, 1] > 0.5) and np.abs(local_pos[:, [0, 2]]).max() < 0.5
