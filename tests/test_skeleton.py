"""The canonical skeleton: joint order, hierarchy, mirroring and the reference body."""

from __future__ import annotations

import numpy as np
import pytest

from posecast.geometry.fk import fk_positions
from posecast.skeleton import (
    FEET,
    JOINT_NAMES,
    LOWER_BODY,
    MIRROR,
    MIRROR_INDEX,
    NUM_JOINTS,
    NUM_ROTATIONS,
    PARENT,
    PARENTS,
    REST_PELVIS_HEIGHT_M,
    REST_TOE_HEIGHT_M,
    TOES,
    Joint,
    children,
    reference_offsets,
)


def rest_positions() -> np.ndarray:
    """World joint positions of the reference body in its rest pose, feet down."""
    local = np.broadcast_to(np.eye(3), (NUM_JOINTS, 3, 3))
    return fk_positions(local, [0.0, REST_PELVIS_HEIGHT_M, 0.0], reference_offsets())


def test_counts_and_names() -> None:
    assert NUM_JOINTS == 19
    assert NUM_ROTATIONS == 18
    assert tuple(j.name for j in Joint) == JOINT_NAMES
    assert [int(j) for j in Joint] == list(range(NUM_JOINTS))


def test_parents_come_before_children() -> None:
    assert PARENTS[Joint.PELVIS] == -1
    assert sum(p < 0 for p in PARENTS) == 1
    for j, p in enumerate(PARENTS[1:], start=1):
        assert 0 <= p < j
        assert PARENT[Joint(j)] == Joint(p)


def test_children() -> None:
    assert children(Joint.CHEST) == (Joint.NECK, Joint.LEFT_UPPER_ARM, Joint.RIGHT_UPPER_ARM)
    assert children(Joint.PELVIS) == (Joint.SPINE, Joint.LEFT_THIGH, Joint.RIGHT_THIGH)
    for leaf in (Joint.HEAD, Joint.LEFT_HAND, Joint.RIGHT_HAND, *TOES):
        assert children(leaf) == ()


def test_mirror_swaps_sides_and_is_an_involution() -> None:
    assert MIRROR[Joint.LEFT_HAND] == Joint.RIGHT_HAND
    assert MIRROR[Joint.RIGHT_SHIN] == Joint.LEFT_SHIN
    assert MIRROR[Joint.HEAD] == Joint.HEAD
    for j in Joint:
        assert MIRROR[MIRROR[j]] == j
        assert MIRROR_INDEX[j] == int(MIRROR[j])


def test_reference_body_is_left_right_symmetric() -> None:
    off = reference_offsets()
    mirrored = off[list(MIRROR_INDEX)] * np.array([-1.0, 1.0, 1.0])
    np.testing.assert_array_equal(mirrored, off)


def test_reference_offsets_is_a_fresh_copy() -> None:
    off = reference_offsets()
    off[:] = 7.0
    assert reference_offsets()[Joint.SPINE, 1] == pytest.approx(0.10)


def test_rest_pose_conventions() -> None:
    """+Y up, left is +X, facing +Z, head at 1.60 m, toes on their rest height."""
    p = rest_positions()
    assert p[Joint.HEAD, 1] == pytest.approx(1.60)
    for toe in TOES:
        assert p[toe, 1] == pytest.approx(REST_TOE_HEIGHT_M)
        assert p[toe, 2] > p[Joint.PELVIS, 2]  # the feet point forward, +Z
    for j in Joint:
        if j.name.startswith("LEFT_"):
            assert p[j, 0] > 0.0
        elif j.name.startswith("RIGHT_"):
            assert p[j, 0] < 0.0
        else:
            assert p[j, 0] == 0.0
    # T-pose: the arms lie along X at one height.
    arm = [Joint.LEFT_UPPER_ARM, Joint.LEFT_FOREARM, Joint.LEFT_HAND]
    np.testing.assert_allclose(p[arm, 1], p[Joint.LEFT_UPPER_ARM, 1])
    assert p[Joint.LEFT_HAND, 0] == pytest.approx(0.70)


def test_body_groups() -> None:
    assert set(FEET) | set(TOES) <= set(LOWER_BODY)
    assert len(LOWER_BODY) == 8
    assert all(j.name.split("_")[1] in {"THIGH", "SHIN", "FOOT", "TOE"} for j in LOWER_BODY)
