"""The wrist-bend statistic (:mod:`posecast.offline.dataset.wrists`)."""

from __future__ import annotations

import numpy as np

from posecast.geometry.fk import fk_mat
from posecast.geometry.rotations import aa2mat
from posecast.offline.dataset.wrists import bend_summary, wrist_bend_deg
from posecast.skeleton import Joint, reference_offsets


def _poses(T: int, wrist_deg: float) -> tuple[np.ndarray, np.ndarray]:
    """``T`` random poses whose left wrist bends ``wrist_deg`` about its local z, the
    right one straight."""
    rng = np.random.default_rng(0)
    local = aa2mat(rng.normal(0.0, 0.3, (T, 19, 3)))
    local[:, Joint.LEFT_HAND] = aa2mat(np.tile([0.0, 0.0, np.radians(wrist_deg)], (T, 1)))
    local[:, Joint.RIGHT_HAND] = np.eye(3)
    return fk_mat(local, np.zeros((T, 3)), reference_offsets())


def test_a_bent_wrist_measures_its_bend_a_straight_one_zero() -> None:
    wm, wp = _poses(5, 30.0)
    bend = wrist_bend_deg(wm, wp)
    assert bend.shape == (5, 2)
    np.testing.assert_allclose(bend[:, 0], 30.0, atol=1e-6)
    np.testing.assert_allclose(bend[:, 1], 0.0, atol=1e-5)
    stats = bend_summary([(wm, wp)])
    assert stats["hand_frames"] == 10 and abs(stats["mean_deg"] - 15.0) < 1e-5
    assert bend_summary([]) == {"hand_frames": 0.0}
