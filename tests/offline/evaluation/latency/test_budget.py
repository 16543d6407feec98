"""Capture to display split into its budget (posecast.offline.evaluation.latency.budget)."""

from __future__ import annotations

import numpy as np
import pytest

from posecast.offline.evaluation.latency.budget import COMPONENTS, budget, stats_ms, summary
from posecast.offline.evaluation.latency.display import Displayed


def test_each_pose_splits_into_components_that_add_up() -> None:
    captures = {"a": {1: 10.000, 2: 10.017, 3: 99.0}, "b": {1: 10.005}}
    shown = [
        Displayed("a", 1, t=10.180, received=10.186, shown=10.290),
        Displayed("a", 2, t=10.197, received=10.201, shown=10.300),
        Displayed("b", 1, t=10.180, received=10.190, shown=10.290),
        Displayed("a", 3, t=99.2, received=99.21, shown=99.3),  # captured after the window
        Displayed("c", 1, t=10.2, received=10.21, shown=10.3),  # no capture known
    ]
    b = budget(shown, captures, lookahead_s=10 / 60, tick_s=0.004, window=(10.0, 20.0))
    assert b.count == 3
    np.testing.assert_allclose(b.total, [0.290, 0.283, 0.285])
    np.testing.assert_allclose(sum(b.parts[c] for c in COMPONENTS), b.total)
    np.testing.assert_allclose(b.parts["lookahead"], 10 / 60)
    np.testing.assert_allclose(b.parts["server_queue_tick"][0], 0.180 + 0.004 - 10 / 60)
    np.testing.assert_allclose(b.parts["transport"][0], 0.006 - 0.004)
    np.testing.assert_allclose(b.parts["client_buffer"], [0.104, 0.099, 0.100])


def test_summary_names_the_figures_in_milliseconds() -> None:
    b = budget(
        [Displayed("a", 1, 0.2, 0.21, 0.3)], {"a": {1: 0.0}}, lookahead_s=0.1, tick_s=0.0,
        window=(0.0, 1.0),
    )  # fmt: skip
    s = summary(b)
    assert s["capture_to_display_ms_p50"] == s["capture_to_display_ms_p99"] == 300.0
    assert set(s["components_ms"]) == set(COMPONENTS)
    assert s["components_ms"]["client_buffer"] == {"p50": 90.0, "p99": 90.0, "mean": 90.0,
                                                   "max": 90.0}  # fmt: skip
    assert s["poses_displayed"] == 1


def test_no_poses_give_no_figures() -> None:
    b = budget([], {}, lookahead_s=0.1, tick_s=0.0, window=(0.0, 1.0))
    assert b.count == 0
    assert summary(b)["capture_to_display_ms_p50"] is None
    assert stats_ms(np.array([0.001, 0.002]))["mean"] == pytest.approx(1.5)
