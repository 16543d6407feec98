"""Tracker slots and the 24 input features (posecast.tracking.features)."""

from __future__ import annotations

import numpy as np
import pytest

from posecast.geometry.rotations import mat2quat, quat_apply, quat_mul, quat_normalize, yaw2quat
from posecast.offline.motion.synthetic import walk_clip
from posecast.skeleton import Joint
from posecast.tracking.features import (
    FEATURE_NAMES,
    NUM_FEATURES,
    TRACKER_JOINT,
    TrackerSlot,
    clip_features,
    from_character_frame,
    to_character_frame,
    tracker_features,
    trackers_from_pose,
)

FPS = 60.0


def _col(name: str) -> int:
    return FEATURE_NAMES.index(name)


@pytest.fixture(scope="module")
def walk_trackers() -> tuple[np.ndarray, np.ndarray]:
    """Synthetic trackers ``(F, 4, 3)``, ``(F, 4, 4)`` of a procedural walk at 60 fps."""
    clip = walk_clip(seconds=2.0, fps=FPS, seed=3)
    return trackers_from_pose(*clip.fk())


def _still_trackers(waist_yaw: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
    """One frame of hand-placed trackers, the waist turned by ``waist_yaw`` about +Y."""
    pos = np.array(
        [
            [0.0, 1.60, 0.0],  # head
            [0.70, 1.40, 0.10],  # left hand
            [-0.70, 1.40, 0.20],  # right hand
            [0.0, 0.98, 0.0],  # waist
        ]
    )
    quat = np.zeros((4, 4))
    quat[:, 3] = 1.0
    quat[TrackerSlot.WAIST] = yaw2quat(waist_yaw)
    return pos, quat


def test_feature_names_are_24_in_slot_then_position_then_velocity_order() -> None:
    assert NUM_FEATURES == 24
    assert len(FEATURE_NAMES) == 24
    expected = [
        f"{slot}.{kind}{axis}"
        for slot in ("HEAD", "LEFT_HAND", "RIGHT_HAND", "WAIST")
        for kind in "pv"
        for axis in "xyz"
    ]
    assert list(FEATURE_NAMES) == expected


def test_tracker_slots_sit_on_their_joints() -> None:
    assert [s.name for s in TrackerSlot] == ["HEAD", "LEFT_HAND", "RIGHT_HAND", "WAIST"]
    assert TRACKER_JOINT[TrackerSlot.WAIST] is Joint.PELVIS
    clip = walk_clip(seconds=0.5, fps=FPS, seed=1)
    wm, wp = clip.fk()
    pos, quat = trackers_from_pose(wm, wp)
    assert pos.shape == (clip.n_frames, 4, 3)
    assert quat.shape == (clip.n_frames, 4, 4)
    for slot, joint in TRACKER_JOINT.items():
        np.testing.assert_array_equal(pos[:, slot], wp[:, joint])
        np.testing.assert_allclose(quat[:, slot], mat2quat(wm[:, joint]), atol=1e-12)


def test_features_of_a_still_pose_are_positions_in_the_character_frame() -> None:
    pos, quat = _still_trackers()
    feat = tracker_features(pos, pos, quat[TrackerSlot.WAIST], FPS)
    assert feat.shape == (24,)
    # Waist faces +Z with no yaw: the character frame is the world shifted to the waist's XZ.
    for slot in TrackerSlot:
        for k, axis in enumerate("xyz"):
            want = pos[slot, k] - (0.0 if axis == "y" else pos[TrackerSlot.WAIST, k])
            assert feat[_col(f"{slot.name}.p{axis}")] == pytest.approx(want)
            assert feat[_col(f"{slot.name}.v{axis}")] == 0.0


def test_waist_is_at_the_origin_in_x_and_z_and_keeps_its_height(walk_trackers) -> None:
    pos, quat = walk_trackers
    feat = clip_features(pos, quat, FPS)
    assert np.abs(pos[:, TrackerSlot.WAIST, [0, 2]]).max() > 0.5  # the walk goes places
    np.testing.assert_allclose(feat[:, _col("WAIST.px")], 0.0, atol=1e-12)
    np.testing.assert_allclose(feat[:, _col("WAIST.pz")], 0.0, atol=1e-12)
    np.testing.assert_allclose(feat[:, _col("WAIST.py")], pos[:, TrackerSlot.WAIST, 1])


def test_left_is_plus_x_in_the_character_frame_whatever_the_heading() -> None:
    # A figure facing +X (yaw +90 deg) has its left hand at world -Z.
    pos, quat = _still_trackers(waist_yaw=np.pi / 2)
    pos[TrackerSlot.LEFT_HAND] = [0.0, 1.4, -0.7]
    pos[TrackerSlot.RIGHT_HAND] = [0.0, 1.4, 0.7]
    feat = tracker_features(pos, pos, quat[TrackerSlot.WAIST], FPS)
    assert feat[_col("LEFT_HAND.px")] == pytest.approx(0.7)
    assert feat[_col("RIGHT_HAND.px")] == pytest.approx(-0.7)
    assert feat[_col("LEFT_HAND.pz")] == pytest.approx(0.0, abs=1e-12)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_features_are_invariant_to_turning_and_moving_the_whole_scene(
    walk_trackers, seed: int
) -> None:
    pos, quat = walk_trackers
    rng = np.random.default_rng(seed)
    yaw = rng.uniform(-np.pi, np.pi)
    shift = np.array([rng.uniform(-5, 5), 0.0, rng.uniform(-5, 5)])
    turn = yaw2quat(yaw)
    pos2 = quat_apply(turn, pos) + shift
    quat2 = quat_mul(turn, quat)
    before = clip_features(pos, quat, FPS)
    after = clip_features(pos2, quat2, FPS)
    assert np.abs(pos2 - pos).max() > 0.5  # the scene really moved
    np.testing.assert_allclose(after, before, atol=1e-9)


def test_lifting_the_scene_changes_heights_only(walk_trackers) -> None:
    pos, quat = walk_trackers
    lifted = pos + np.array([0.0, 0.3, 0.0])
    before = clip_features(pos, quat, FPS)
    after = clip_features(lifted, quat, FPS)
    py = [_col(f"{s.name}.py") for s in TrackerSlot]
    others = [i for i in range(24) if i not in py]
    np.testing.assert_allclose(after[:, py], before[:, py] + 0.3, atol=1e-12)
    np.testing.assert_allclose(after[:, others], before[:, others], atol=1e-12)


def test_velocities_are_metres_per_second() -> None:
    # The head moves 1 cm per frame along +Z at 60 fps: 0.6 m/s forward.
    pos, quat = _still_trackers()
    nxt = pos.copy()
    nxt[TrackerSlot.HEAD, 2] += 0.01
    feat = tracker_features(nxt, pos, quat[TrackerSlot.WAIST], 60.0)
    assert feat[_col("HEAD.vz")] == pytest.approx(0.6)
    assert feat[_col("HEAD.vx")] == pytest.approx(0.0, abs=1e-12)
    assert feat[_col("HEAD.vy")] == pytest.approx(0.0, abs=1e-12)
    assert feat[_col("LEFT_HAND.vz")] == 0.0
    # The same step measured at 120 fps is twice as fast.
    feat120 = tracker_features(nxt, pos, quat[TrackerSlot.WAIST], 120.0)
    assert feat120[_col("HEAD.vz")] == pytest.approx(1.2)


def test_velocities_are_turned_into_the_character_frame() -> None:
    # Facing +X and stepping 1 cm per frame along world +X is moving forward (+Z).
    pos, quat = _still_trackers(waist_yaw=np.pi / 2)
    nxt = pos + np.array([0.01, 0.0, 0.0])
    feat = tracker_features(nxt, pos, quat[TrackerSlot.WAIST], 60.0)
    for slot in TrackerSlot:
        assert feat[_col(f"{slot.name}.vz")] == pytest.approx(0.6)
        assert feat[_col(f"{slot.name}.vx")] == pytest.approx(0.0, abs=1e-12)


def test_first_frame_velocity_is_zero_and_later_ones_are_finite_differences(
    walk_trackers,
) -> None:
    pos, quat = walk_trackers
    feat = clip_features(pos, quat, FPS)
    v_cols = [i for i, n in enumerate(FEATURE_NAMES) if ".v" in n]
    assert len(v_cols) == 12
    np.testing.assert_array_equal(feat[0, v_cols], 0.0)
    speed_head = np.linalg.norm(
        feat[1:, [_col("HEAD.vx"), _col("HEAD.vy"), _col("HEAD.vz")]], axis=1
    )
    expected = np.linalg.norm(np.diff(pos[:, TrackerSlot.HEAD], axis=0), axis=1) * FPS
    np.testing.assert_allclose(speed_head, expected, atol=1e-9)
    assert expected.max() > 0.5  # the head really moves


def test_streaming_one_frame_at_a_time_equals_the_batch(walk_trackers) -> None:
    pos, quat = walk_trackers
    batch = clip_features(pos, quat, FPS)
    assert batch.shape == (len(pos), 24)
    for t in range(len(pos)):
        prev = pos[t - 1] if t > 0 else pos[t]
        one = tracker_features(pos[t], prev, quat[t, TrackerSlot.WAIST], FPS)
        np.testing.assert_allclose(one, batch[t], rtol=0, atol=1e-12, err_msg=f"frame {t}")


def test_from_character_frame_inverts_to_character_frame() -> None:
    rng = np.random.default_rng(3)
    points = rng.normal(size=(5, 3))
    waist_pos = np.array([1.5, 0.9, -2.0])
    waist_quat = quat_normalize(rng.normal(size=4))
    local = to_character_frame(points, waist_pos, waist_quat)
    np.testing.assert_allclose(
        from_character_frame(local, waist_pos, waist_quat), points, atol=1e-12
    )
