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


def test_node_clocks_map_another_epoch_to_this_one() -> None:
    from posecast.online.core.clock import FORGET_S, RESET_S, RISE_S_PER_S, NodeClocks

    c = NodeClocks()
    # Node B's clock is 1000 s ahead; delays 5, 3, 8 ms: the least one sets the offset,
    # which may rise by RISE_S_PER_S a second (drift, a path slower for good).
    assert c.local("b", 2000.0, 1000.005) == pytest.approx(1000.005, abs=1e-9)
    assert c.local("b", 2001.0, 1001.003) == pytest.approx(1001.003, abs=1e-9)
    rise = RISE_S_PER_S * 1.005
    assert c.local("b", 2002.0, 1002.008) == pytest.approx(1002.003 + rise, abs=1e-9)
    rise += RISE_S_PER_S * 10.012
    assert c.local("b", 2012.0, 1012.020) == pytest.approx(1012.003 + rise, abs=1e-9)
    # Node C is another node with its own offset.
    assert c.local("c", 3.0, 1012.5) == pytest.approx(1012.5, abs=1e-9)
    # B restarted: its clock jumped back; above the offset by more than RESET_S.
    assert c.local("b", 10.0, 1013.0) == pytest.approx(1013.0)
    assert c.local("b", 10.0 + RESET_S / 2, 1013.0 + RESET_S / 2) == pytest.approx(
        1013.0 + RESET_S / 2
    )
    # A node silent for FORGET_S is dropped when another one appears.
    c.local("d", 0.0, 1014.0 + FORGET_S + 1)
    assert len(c) == 1


def test_node_clocks_keep_each_players_time_moving_on() -> None:
    from posecast.online.core.clock import MIN_STEP_S, NodeClocks

    c = NodeClocks()
    assert c.local("b", 10.0, 100.100, "m") == pytest.approx(100.100, abs=1e-9)
    # q's newer pose with less delay lowers the offset by 95 ms; m's older pose in the
    # same batch would map before m's last time: it moves on from there instead.
    assert c.local("b", 10.1, 100.105, "q") == pytest.approx(100.105, abs=1e-9)
    assert c.local("b", 10.0667, 100.105, "m") == pytest.approx(100.100 + MIN_STEP_S, abs=1e-9)
    assert c.local("b", 10.2, 100.205, "m") == pytest.approx(100.205, abs=1e-6)
    # Forgotten (m left): its next time is the node's mapping again, even if earlier.
    c.local("b", 10.3, 100.305, "m")
    c.forget("m", "b")
    assert c.local("b", 10.25, 100.31, "m") == pytest.approx(100.255, abs=1e-4)
    c.forget("q")  # of any node
    assert c.local("b", 10.0, 100.4, "q") == pytest.approx(100.005, abs=1e-3)
    # Retained for the nodes that still have it: another node's guard goes, b's stays.
    last = c.local("b", 10.1, 100.5, "q")
    c.local("c", 50.0, 100.5, "q")
    c.retain("q", {"b"})
    assert c.guarded == 2  # (b, m), (b, q)
    assert c.local("b", 10.05, 100.5, "q") == pytest.approx(last + MIN_STEP_S, abs=1e-9)
    c.retain("q", ())
    assert c.guarded == 1


def test_node_clocks_drop_the_player_times_of_a_forgotten_node() -> None:
    from posecast.online.core.clock import FORGET_S, NodeClocks

    c = NodeClocks()
    c.local("b", 10.0, 100.0, "m")
    c.local("b", 10.0, 100.0, "q")
    c.local("c", 10.0, 100.0, "q")
    assert c.guarded == 3
    c.local("c", 10.0 + FORGET_S, 100.0 + FORGET_S, "q")  # b silent since
    c.local("d", 0.0, 101.0 + FORGET_S)  # a new node: b is forgotten, with its players
    assert c.guarded == 1  # (c, q)


def test_frames_that_queued_during_a_stall_are_judged_by_their_own_times() -> None:
    from posecast.online.core.clock import FrameTimes

    ft = FrameTimes()
    offset = 500.0  # the server's clock is 500 s ahead of the client's
    judged = [ft.judge(k / 60, offset + k / 60 + 0.003)[0] for k in range(60)]
    # a 3 s stall: the next 180 frames all reach the event loop at once
    arrive = offset + 60 / 60 + 3.0
    burst = [ft.judge(k / 60, arrive) for k in range(60, 240)]
    assert [odd for _, odd in burst] == [None] * 180
    times = np.array(judged + [j for j, _ in burst])
    np.testing.assert_allclose(np.diff(times), 1 / 60, atol=1e-9)  # spaced as sampled
    assert times[-1] <= arrive


def test_a_frame_clock_that_runs_ahead_or_lies_gains_nothing_over_arrival() -> None:
    from posecast.online.core.clock import FrameTimes

    ft = FrameTimes()
    last = float("-inf")
    for k in range(1000):
        now = 10.0 + k * 0.001  # 1,000 frames a second
        judged, _ = ft.judge(k * 0.1, now)  # claiming 10 Hz-spaced... at 100x speed
        assert last <= judged <= now
        last = judged


@pytest.mark.parametrize(
    ("t2", "odd"),
    [(1.0, "repeat"), (0.9, "backwards"), (-5.0, "jump"), (1e6, "jump"), (1.0 + 1 / 60, None)],
)
def test_odd_frame_times_are_named_and_judged_on_arrival(t2: float, odd: str | None) -> None:
    from posecast.online.core.clock import FrameTimes

    ft = FrameTimes()
    ft.judge(1.0, 100.0)
    judged, got = ft.judge(t2, 100.5)
    assert got == odd
    assert judged == (100.5 if odd else pytest.approx(100.0 + 1 / 60))


def test_a_client_clock_set_ahead_starts_a_new_epoch_and_no_absurd_drift() -> None:
    """One session whose frame times jumped 1e6 s ahead added 1.08e16 ppm to the drift
    histogram's sum: the estimator fitted one line across the jump."""
    clock = ClockEstimator()
    for i in range(60 * 10):
        clock.add(1000.0 + i / 60, i / 60)
    for i in range(60 * 10, 60 * 20):
        clock.add(1000.0 + i / 60, i / 60 + 1e6)
    assert clock.offset_s == pytest.approx(1000.0 - 1e6, abs=0.01)
    drift = clock.drift_ppm
    assert drift is None or abs(drift) < 1.0
