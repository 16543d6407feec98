"""The toe-clearance table (:mod:`posecast.offline.dataset.clearance`) on clips whose
toes' speeds and heights are known."""

from __future__ import annotations

import numpy as np

from posecast.body.clearance import SPEEDS_M_S, TOES
from posecast.offline.dataset.clearance import EDGES_M_S, clearance_table, toe_speed_height


def _clip(speed_m_s: float, heights: np.ndarray, fps: float = 60.0) -> np.ndarray:
    """Both toes moving along x at ``speed_m_s`` with the heights given (one per frame)."""
    pos = np.zeros((len(heights), 19, 3))
    pos[:, TOES, 0] = (np.arange(len(heights)) * speed_m_s / fps)[:, None]
    pos[:, TOES, 1] = heights[:, None]
    return pos


def test_speeds_and_heights_pair_each_step_with_its_later_frame() -> None:
    speed, height = toe_speed_height(_clip(1.2, np.array([0.1, 0.2, 0.3])), 60.0)
    np.testing.assert_allclose(speed, [1.2] * 4)
    np.testing.assert_allclose(height, [0.2, 0.2, 0.3, 0.3])


def test_the_table_is_a_percentile_per_bin_never_falling_with_speed() -> None:
    rng = np.random.default_rng(0)
    slow = _clip(0.1, rng.uniform(0.02, 0.04, 2001))  # bin 0: 5th percentile near 0.021
    fast = _clip(2.2, rng.uniform(0.05, 0.09, 2001))  # the 2-2.5 m/s bin: near 0.052
    sliding = _clip(3.5, np.full(11, 0.01))  # 3-4 m/s, low: held at the bin below's
    centres, heights, counts = clearance_table([slow, fast, sliding], 60.0, 5.0)
    assert centres == SPEEDS_M_S and len(centres) == len(EDGES_M_S) - 1
    assert counts[0] == counts[7] == 4000 and counts[9] == 20 and sum(counts) == 8020
    assert abs(heights[0] - 0.021) <= 0.001 and abs(heights[7] - 0.052) <= 0.001
    assert heights[1:7] == (heights[0],) * 6  # empty bins: the one below
    assert heights[8:] == (heights[7],) * 3
    assert clearance_table([], 60.0) == (SPEEDS_M_S, (0.0,) * len(SPEEDS_M_S), (0,) * 11)
