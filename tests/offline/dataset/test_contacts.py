"""Foot-contact labels (posecast.offline.dataset.contacts), checked against Sec. 4.1's rule.

The rule, worked by hand in each test: a toe is in contact when its height is below
``min over toes of (per-toe 10th percentile height) + 5 cm`` AND its Savitzky-Golay
(11, 3) smoothed speed is below 1 cm per frame at 60 fps (0.6 m/s).
"""

from __future__ import annotations

import numpy as np
import pytest

from posecast.offline.dataset.contacts import foot_contacts, smoothed_velocity

LEFT, RIGHT = 0, 1
FLOOR = 0.02  # toe joint height when the foot is flat on the floor


def _still(n: int, left_y: float, right_y: float) -> np.ndarray:
    """``(n, 2, 3)`` toes standing still at the given heights, 20 cm apart."""
    toes = np.zeros((n, 2, 3))
    toes[:, LEFT] = [0.1, left_y, 0.0]
    toes[:, RIGHT] = [-0.1, right_y, 0.0]
    return toes


def test_hand_made_step_and_slide() -> None:
    n = 80
    t = np.arange(n)
    toes = _still(n, FLOOR, FLOOR)
    # Left toe rests on the floor for frames 0-39, then lifts 4 cm per frame (2.4 m/s)
    # to 20 cm above the floor and holds there.
    toes[:, LEFT, 1] = np.minimum(FLOOR + 0.04 * np.maximum(t - 39, 0), FLOOR + 0.20)
    # Right toe slides forward at floor height, 2 cm per frame (1.2 m/s).
    toes[:, RIGHT, 2] = 0.02 * t

    # By hand: both toes spend at least half the clip at 2 cm, so both 10th
    # percentiles are 2 cm and the height threshold is 2 + 5 = 7 cm.
    # Left: frames 0-34 are low and their 11-frame window (t-5..t+5) is flat, so the
    # smoothed speed is 0: contact. From frame 41 on the toe is >= 10 cm high: no
    # contact whatever the speed. Frames 35-40 are the transition: not asserted.
    # Right: always low, but a straight line's Savitzky-Golay slope is exact, 1.2 m/s
    # > 0.6 m/s everywhere (edges included): never in contact.
    got = foot_contacts(toes, fps=60.0)
    assert got.shape == (n, 2)
    assert got.dtype == np.bool_
    np.testing.assert_array_equal(got[:35, LEFT], True)
    np.testing.assert_array_equal(got[41:, LEFT], False)
    np.testing.assert_array_equal(got[:, RIGHT], False)


def test_a_slow_slide_is_contact_and_a_fast_one_is_not() -> None:
    n = 60
    toes = _still(n, FLOOR, FLOOR)
    toes[:, LEFT, 2] = 0.005 * np.arange(n)  # 0.5 cm/frame = 0.3 m/s
    toes[:, RIGHT, 2] = 0.015 * np.arange(n)  # 1.5 cm/frame = 0.9 m/s
    got = foot_contacts(toes, fps=60.0)
    np.testing.assert_array_equal(got[:, LEFT], True)
    np.testing.assert_array_equal(got[:, RIGHT], False)


def test_speed_limit_is_in_metres_per_second_not_per_frame() -> None:
    # 0.75 cm per frame is 0.45 m/s at 60 fps (contact) but 0.9 m/s at 120 fps (not).
    n = 60
    toes = _still(n, FLOOR, FLOOR)
    toes[:, LEFT, 2] = 0.0075 * np.arange(n)
    assert foot_contacts(toes, fps=60.0)[:, LEFT].all()
    assert not foot_contacts(toes, fps=120.0)[:, LEFT].any()


def test_smoothed_velocity_is_the_slope_in_metres_per_second() -> None:
    n = 30
    pos = np.zeros((n, 3))
    pos[:, 0] = 0.01 * np.arange(n)  # 1 cm per frame
    np.testing.assert_allclose(smoothed_velocity(pos, 60.0), [[0.6, 0.0, 0.0]] * n, atol=1e-12)


def test_jitter_is_smoothed_before_the_speed_test() -> None:
    # A toe standing still with +-6 mm frame-to-frame marker jitter: the raw finite
    # difference is 1.2 cm per frame (0.72 m/s, above the limit), the Savitzky-Golay
    # velocity is near zero, so the toe is in contact throughout.
    n = 60
    toes = _still(n, FLOOR, FLOOR)
    toes[:, LEFT, 1] += 0.006 * (-1.0) ** np.arange(n)
    raw_speed = np.abs(np.diff(toes[:, LEFT, 1])) * 60.0
    assert raw_speed.min() > 0.6
    assert foot_contacts(toes, fps=60.0).all()


@pytest.mark.parametrize(
    ("above_m", "contact"), [(0.0, True), (0.04, True), (0.06, False), (0.30, False)]
)
def test_height_threshold_is_lowest_toe_percentile_plus_5cm(above_m: float, contact: bool) -> None:
    # Right toe flat on the floor (percentile 0.0 m), left toe held still `above_m`
    # higher: threshold is 0.0 + 5 cm, shared by both toes.
    toes = _still(50, above_m, 0.0)
    got = foot_contacts(toes, fps=60.0)
    np.testing.assert_array_equal(got[:, RIGHT], True)
    np.testing.assert_array_equal(got[:, LEFT], contact)


def test_threshold_uses_the_10th_percentile_not_the_minimum() -> None:
    # One glitch frame puts the left toe 50 cm below the floor. The 10th percentile of
    # its 100 heights is still 0.0, so a right toe 4 cm up is in contact. (With the
    # minimum the threshold would be -45 cm and nothing would be.)
    toes = _still(100, 0.0, 0.04)
    toes[70, LEFT, 1] = -0.5
    got = foot_contacts(toes, fps=60.0)
    np.testing.assert_array_equal(got[:, RIGHT], True)


def test_threshold_follows_the_sequence_floor() -> None:
    # The same motion captured 1 m higher (a stage) gets the same labels: the
    # threshold is per sequence, not absolute.
    n = 80
    toes = _still(n, FLOOR, FLOOR)
    toes[:, LEFT, 1] = FLOOR + 0.2 * (np.arange(n) >= 40)
    toes[:, RIGHT, 2] = 0.005 * np.arange(n)
    lifted = toes + np.array([0.0, 1.0, 0.0])
    np.testing.assert_array_equal(foot_contacts(lifted, 60.0), foot_contacts(toes, 60.0))
    assert foot_contacts(toes, 60.0).any()


@pytest.mark.parametrize("n", range(1, 11))
def test_clips_shorter_than_the_filter_window(n: int) -> None:
    still = foot_contacts(_still(n, FLOOR, FLOOR), fps=60.0)
    assert still.shape == (n, 2)
    assert still.all()
    if n >= 2:
        moving = _still(n, FLOOR, FLOOR)
        moving[:, :, 2] = 0.02 * np.arange(n)[:, None]  # 1.2 m/s
        assert not foot_contacts(moving, fps=60.0).any()
