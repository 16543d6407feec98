"""Anomaly scores R of world poses (paper Sec. 3.2.1) from the shipped autoencoder, and
every backend's candidate pool against them."""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
import pytest

from posecast.body.batch_fk import fk32
from posecast.body.pelvis import PelvisPoses
from posecast.geometry.rotations import normalize, quat2mat, quat_apply, quat_mul, yaw2quat
from posecast.online.engine.ports import PoolIK
from posecast.online.inference.anomaly import AnomalyScorer, rotate_y
from posecast.skeleton import NUM_JOINTS, Joint
from posecast.tracking.features import TrackerSlot, character_frame, to_character_frame
from tests.online.engine.conftest import BackendLoader

Walk = Callable[[int], dict[str, np.ndarray]]
LEFT_BELOW_HIP = [Joint.LEFT_SHIN, Joint.LEFT_FOOT, Joint.LEFT_TOE]
RIGHT_BELOW_HIP = [Joint.RIGHT_SHIN, Joint.RIGHT_FOOT, Joint.RIGHT_TOE]


def walk_pose_batch(walk_arrays: Walk) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Ground-truth world positions ``(F, 19, 3)`` and waist trackers of a walk."""
    w = walk_arrays(0)
    return (
        w["positions"],
        w["tracker_pos"][:, TrackerSlot.WAIST],
        w["tracker_quat"][:, TrackerSlot.WAIST],
    )


def test_score_mats_ignores_heading_and_place(walk_arrays: Walk, rng: np.random.Generator) -> None:
    """Scores from pelvis matrices (the headset-only model's path) depend on the pose,
    not on where the player stands or which way it faces: turning and moving the poses
    and their pelvis together changes no score."""
    from posecast.online.inference.artifact import load_artifact

    scorer = AnomalyScorer(load_artifact("anomaly"))
    pos, waist_pos, waist_quat = walk_pose_batch(walk_arrays)
    pos, waist_pos, waist_quat = pos[:32], waist_pos[:32], waist_quat[:32]
    root = quat2mat(waist_quat)
    a = scorer.score_mats(pos, waist_pos, root)
    turn, shift = quat2mat(yaw2quat(1.1)), np.array([3.0, 0.0, -2.0])
    b = scorer.score_mats(pos @ turn.T + shift, waist_pos @ turn.T + shift, turn @ root)
    np.testing.assert_allclose(a, b, atol=1e-5)
    c = scorer.score_mats(pos, waist_pos, quat2mat(normalize(rng.normal(size=(32, 4)))))
    assert np.abs(c - a).max() > 1e-2  # a wrong pelvis rotation does change the scores


def test_rotate_y_matches_to_character_frame(rng: np.random.Generator) -> None:
    """The scorer's cheap yaw-only rotation equals the general character-frame move,
    for waists that pitch and roll as well as turn."""
    points = rng.normal(size=(16, 19, 3))
    waist_pos = rng.normal(size=(16, 3))
    waist_quat = normalize(rng.normal(size=(16, 4)))
    origin, inv_yaw = character_frame(waist_pos, waist_quat)
    angle = 2.0 * np.arctan2(inv_yaw[:, 1], inv_yaw[:, 3])
    got = rotate_y(points - origin[:, None, :], angle)
    np.testing.assert_allclose(got, to_character_frame(points, waist_pos, waist_quat), atol=1e-12)


def test_scores_are_per_pose_metres(scorer: AnomalyScorer, walk_arrays: Walk) -> None:
    pos, wpos, wquat = walk_pose_batch(walk_arrays)
    r = scorer.score(pos, wpos, wquat)
    assert r.shape == (len(pos),)
    assert np.all(np.isfinite(r))
    assert np.all(r >= 0.0)
    assert np.all(r < 1.0)  # metres: a lower-body error of a metre would be absurd
    # Batched scoring equals scoring one pose at a time.
    one = np.concatenate(
        [scorer.score(pos[i : i + 1], wpos[i : i + 1], wquat[i : i + 1]) for i in (0, 7, 42)]
    )
    np.testing.assert_allclose(one, r[[0, 7, 42]], atol=1e-6)


def test_threshold_comes_from_the_sidecar(scorer: AnomalyScorer) -> None:
    assert scorer.threshold_m == scorer.artifact.meta["implausible_threshold_m"]
    assert 0.0 < scorer.threshold_m < 1.0


def test_scores_ignore_where_the_player_stands_and_faces(
    scorer: AnomalyScorer, walk_arrays: Walk
) -> None:
    """Move the whole walk 3 m and turn it 100 degrees about +Y: R is unchanged."""
    pos, wpos, wquat = walk_pose_batch(walk_arrays)
    turn = yaw2quat(np.radians(100.0))
    shift = np.array([3.0, 0.0, -1.0])
    moved = quat_apply(turn, pos) + shift
    mwpos = quat_apply(turn, wpos) + shift
    mwquat = quat_mul(turn, wquat)
    np.testing.assert_allclose(
        scorer.score(moved, mwpos, mwquat), scorer.score(pos, wpos, wquat), atol=1e-4
    )


@pytest.mark.parametrize("garble", ["crossed", "flipped"])
def test_real_poses_score_lower_than_garbled_ones(
    scorer: AnomalyScorer, walk_arrays: Walk, garble: str
) -> None:
    """Ground-truth walk poses against the same poses with the legs garbled:

    * ``crossed``: shins, feet and toes swap sides under fixed hips (knees crossed);
    * ``flipped``: everything below the hips mirrored about pelvis height (feet up).
    """
    pos, wpos, wquat = walk_pose_batch(walk_arrays)
    bad = pos.copy()
    if garble == "crossed":
        bad[:, LEFT_BELOW_HIP], bad[:, RIGHT_BELOW_HIP] = (
            pos[:, RIGHT_BELOW_HIP],
            pos[:, LEFT_BELOW_HIP],
        )
    else:
        below = LEFT_BELOW_HIP + RIGHT_BELOW_HIP
        bad[:, below, 1] = 2.0 * pos[:, [Joint.PELVIS], 1] - pos[:, below, 1]
    real = scorer.score(pos, wpos, wquat)
    garbled = scorer.score(bad, wpos, wquat)
    assert real.mean() < garbled.mean()


@pytest.mark.parametrize("group", [1, 3])
def test_every_backends_pool_scores_like_the_scorer(
    backend: BackendLoader, scorer: AnomalyScorer, walk_arrays: Walk, group: int
) -> None:
    """A backend's candidate pool on ground-truth walk rotations, contacts off (no IK):
    its world positions are the float32 FK's and its errors the scorer's, with each
    pelvis shared by ``group`` rows as a waist tracker is by a player's samples."""
    w = walk_arrays(0)
    rot = w["rot6d"].reshape(-1, 108).astype(np.float32)  # (R, 108)
    R = len(rot) // group * group
    rot = rot[:R]
    root_mat = quat2mat(w["root_quat"][:R:group]).astype(np.float32)  # (R / group, 3, 3)
    root_pos = w["root_pos"][:R:group].astype(np.float32)
    ik = PoolIK(
        np.zeros((R, 2), bool),
        np.zeros((R, 2, 3)),
        np.zeros((R, 2), np.int64),
        np.zeros((R, 2), bool),
    )
    world = np.full((R, NUM_JOINTS, 3), np.nan, np.float32)
    pool = backend().pool
    pelvis = PelvisPoses(root_mat, root_pos, group)
    got = pool.step(rot, np.zeros((R, 2), np.float32), pelvis, ik, world)
    mats, places = np.repeat(root_mat, group, axis=0), np.repeat(root_pos, group, axis=0)
    _, want = fk32(rot, mats, places, want_mats=False)
    np.testing.assert_allclose(world, want, atol=1e-5)
    assert got.shape == (R,) and got.dtype == np.float64
    np.testing.assert_allclose(got, scorer.score_mats(want, places, mats), atol=1e-5)
    assert pool.threshold_m == scorer.threshold_m
    assert not ik.locked.any()
