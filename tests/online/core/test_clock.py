"""Clock offset and drift (posecast.online.core.clock)."""

from __future__ import annotations

import numpy as np
import pytest

from posecast.online.core.clock import ClockEstimator


def test_offset_is_the_least_delayed_sample_and_drift_the_slope() -> None:
    rng = np.random.default_rng(0)
    clock = ClockEstimator()
    assert clock.offset_s is None and clock.drift_ppm is None
    for i in range(60 * 30):  # 30 s of 60 Hz frames
        server_t = 1000.0 + i / 60
        client_t = server_t * (1 - 100e-6) - 3.0  # 3 s behind, running 100 ppm slow
        delay = 0.002 + rng.exponential(0.004)
        clock.add(server_t + delay, client_t)
    assert clock.offset_s is not None
    # server - client = 3 s + 100 ppm of ~1030 s + the least delay (2 ms)
    assert clock.offset_s == pytest.approx(3.0 + 1e-4 * 1030 + 0.002, abs=0.005)
    assert clock.drift_ppm == pytest.approx(100.0, abs=20.0)
