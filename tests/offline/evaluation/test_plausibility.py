"""The independent plausibility checks: each category fires on the pose it describes and
not on a standing rest pose."""

from __future__ import annotations

import numpy as np

from posecast.geometry.fk import fk_mat
from posecast.geometry.rotations import aa2mat
from posecast.offline.evaluation import plausibility as pl
from posecast.skeleton import NUM_JOINTS, REST_PELVIS_HEIGHT_M, Joint, reference_offsets

FPS = 60.0


def _pose(local: np.ndarray, root_y: float = REST_PELVIS_HEIGHT_M) -> tuple[np.ndarray, np.ndarray]:
    """FK of local rotations ``(T, 19, 3, 3)`` with the pelvis at ``root_y``."""
    root = np.zeros((len(local), 3))
    root[:, 1] = root_y
    return fk_mat(local, root, reference_offsets())


def _rest(frames: int = 4) -> np.ndarray:
    return np.tile(np.eye(3), (frames, NUM_JOINTS, 1, 1))


def _rot(axis: tuple[float, float, float], deg: float) -> np.ndarray:
    return aa2mat(np.radians(deg) * np.asarray(axis, np.float64))


def test_a_standing_rest_pose_is_not_flagged() -> None:
    wm, wp = _pose(_rest())
    f = pl.flags(wm, wp, FPS)
    assert set(f) == set(pl.CATEGORIES)
    assert not any(v.any() for v in f.values())


def test_knee_angles_have_the_documented_signs() -> None:
    local = _rest(3)
    local[0, Joint.LEFT_SHIN] = _rot((1, 0, 0), 60.0)  # +X turns the shin backwards: flexion
    local[1, Joint.LEFT_SHIN] = _rot((1, 0, 0), -30.0)  # forwards: hyperextension
    local[2, Joint.LEFT_SHIN] = _rot((0, 0, 1), 40.0)  # +Z turns -Y towards +X: outwards
    a = pl.joint_angles(_pose(local)[0])
    np.testing.assert_allclose(a["knee_flex"][:, 0], [60.0, -30.0, 0.0], atol=1e-6)
    np.testing.assert_allclose(a["knee_side"][:, 0], [0.0, 0.0, 40.0], atol=1e-6)
    assert pl.angle_violation(_pose(local)[0]).tolist() == [False, True, True]


def test_hip_limits() -> None:
    local = _rest(3)
    local[0, Joint.RIGHT_THIGH] = _rot((1, 0, 0), -90.0)  # forward 90 deg: fine
    local[1, Joint.RIGHT_THIGH] = _rot((1, 0, 0), 60.0)  # backward 60 deg: over-extended
    local[2, Joint.RIGHT_THIGH] = _rot((0, 0, 1), 80.0)  # towards +X: the right leg adducted
    wm, _ = _pose(local)
    a = pl.joint_angles(wm)
    np.testing.assert_allclose(a["hip_flex"][:, 1], [90.0, -60.0, 0.0], atol=1e-6)
    np.testing.assert_allclose(a["hip_abd"][:, 1], [0.0, 0.0, -80.0], atol=1e-6)
    assert pl.angle_violation(wm).tolist() == [False, True, True]


def test_crossed_legs_intersect() -> None:
    local = _rest(2)
    # Frame 1: both thighs swung inwards by 15 degrees, so the knees pass through each other.
    local[1, Joint.LEFT_THIGH] = _rot((0, 0, 1), -15.0)
    local[1, Joint.RIGHT_THIGH] = _rot((0, 0, 1), 15.0)
    wm, wp = _pose(local)
    overlap = pl.leg_overlap(wp)
    assert overlap[0] < 0.0 < pl.DEFAULT.overlap_m < overlap[1]
    assert pl.flags(wm, wp, FPS)["self_intersection"].tolist() == [False, True]


def test_segment_distance_is_exact_for_known_cases() -> None:
    p0, p1 = np.array([[0.0, 0, 0]]), np.array([[1.0, 0, 0]])
    # Parallel, crossing at right angles above, and end to end.
    for q0, q1, want in (
        ([0.0, 1, 0], [1.0, 1, 0], 1.0),
        ([0.5, -1, 2], [0.5, 1, 2], 2.0),
        ([3.0, 0, 0], [4.0, 0, 0], 2.0),
    ):
        got = pl._segment_distance(p0, p1, np.array([q0]), np.array([q1]))
        np.testing.assert_allclose(got, [want], atol=1e-12)


def test_floor_counts_only_more_than_two_centimetres_below() -> None:
    wm, wp = _pose(_rest(3))
    lowest = wp[:, [int(Joint.LEFT_TOE), int(Joint.RIGHT_TOE)], 1].min()
    for t, depth in enumerate((0.0, 0.015, 0.03)):
        wp[t, :, 1] -= lowest + depth
    np.testing.assert_allclose(pl.floor_depth(wp), [0.0, 0.015, 0.03], atol=1e-9)
    assert pl.flags(wm, wp, FPS)["floor"].tolist() == [False, False, True]


def test_a_sliding_planted_toe_skates_and_a_lifted_one_does_not() -> None:
    wm, wp = _pose(_rest(3))
    wp[:, :, 1] -= wp[:, int(Joint.LEFT_TOE), 1].min()  # toes on the floor
    step = 2.0 / FPS  # 2 m/s, above the 1.2 m/s bound
    wp[1:, :, 0] += step * np.arange(1, 3)[:, None]
    assert pl.flags(wm, wp, FPS)["skate"].tolist() == [False, True, True]
    wp[:, :, 1] += 0.2  # the same motion in the air is a swing, not a skate
    assert not pl.flags(wm, wp, FPS)["skate"].any()
