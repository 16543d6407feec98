"""The SDK's skeleton and tracker tables are the server's."""

from __future__ import annotations

import numpy as np
import pytest

from posecast_client import skeleton


def test_tables_match_the_server() -> None:
    server = pytest.importorskip("posecast.skeleton")
    tracking = pytest.importorskip("posecast.tracking.features")
    assert skeleton.JOINT_NAMES == server.JOINT_NAMES
    assert skeleton.PARENTS == server.PARENTS
    np.testing.assert_array_equal(skeleton.reference_offsets(), server.reference_offsets())
    assert skeleton.REST_PELVIS_HEIGHT_M == server.REST_PELVIS_HEIGHT_M
    assert [s.name for s in skeleton.TrackerSlot] == [s.name for s in tracking.TrackerSlot]
    assert tuple(map(int, skeleton.TRACKER_JOINTS)) == tracking.TRACKER_JOINT_INDEX


def test_parents_come_first() -> None:
    assert all(p < j for j, p in enumerate(skeleton.PARENTS))
    assert skeleton.children(skeleton.Joint.CHEST) == (3, 5, 8)
