"""The swing clearance (:mod:`posecast.body.clearance`): a toe moving over the
floor is lifted to the height real toes keep at its speed, straight up; the speed
is an average of the horizontal steps. The engine streaming it:
``tests/online/engine/test_shown.py``."""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from posecast.body.clearance import (
    CLEARANCE_M,
    MAX_STEP_M_S,
    SPEED_SMOOTHING,
    SPEEDS_M_S,
    TOES,
    clearance_lift,
    clip_toe_speed,
    toe_speed,
)
from posecast.body.ik import FLOOR_MAX_LIFT_M
from posecast.online.engine.types import TrackerFrame
from posecast.skeleton import Joint

WalkFrames = Callable[..., list[TrackerFrame]]


def _pose(toe_y: tuple[float, float]) -> np.ndarray:
    pos = np.zeros((1, 19, 3))
    pos[0, TOES, 1] = toe_y
    return pos


def test_the_table_rises_with_speed() -> None:
    assert len(SPEEDS_M_S) == len(CLEARANCE_M)
    assert np.all(np.diff(SPEEDS_M_S) > 0)
    assert np.all(np.diff(CLEARANCE_M) >= 0)
    assert 0.015 < CLEARANCE_M[0] < CLEARANCE_M[-1] < 0.08


def test_the_speed_is_an_average_of_the_horizontal_steps() -> None:
    prev = np.zeros((1, 2, 2))
    now = np.array([[[0.01, 0.0], [0.0, 0.0]]])  # 1 cm in x: 0.6 m/s at 60 fps
    speed = toe_speed(prev, now, np.array([[1.0, 1.0]]), 60.0)
    np.testing.assert_allclose(
        speed, [[SPEED_SMOOTHING + (1 - SPEED_SMOOTHING) * 0.6, SPEED_SMOOTHING]]
    )
    clip = np.zeros((3, 19, 3))
    clip[:, TOES[0], 0] = [0.0, 0.01, 0.02]
    clip[:, TOES[0], 1] = [0.5, -0.3, 0.2]  # heights do not count
    want1 = (1 - SPEED_SMOOTHING) * 0.6
    want = [[0.0, 0.0], [want1, 0.0], [SPEED_SMOOTHING * want1 + (1 - SPEED_SMOOTHING) * 0.6, 0]]
    np.testing.assert_allclose(clip_toe_speed(clip, 60.0), want)


def test_a_jump_of_the_whole_body_starts_the_speed_again_from_rest() -> None:
    """Frames resuming after a gap, a new scale, a recentred space: a step faster than
    any toe's is not a foot's speed, so no toe is lifted for it."""
    prev = np.zeros((2, 2, 2))
    now = np.zeros((2, 2, 2))
    now[0, 0, 0] = 0.75  # one toe of pose 0 jumped 0.75 m: 45 m/s
    now[1, :, 0] = (MAX_STEP_M_S - 0.1) / 60.0  # pose 1: both toes just under the limit
    speed = toe_speed(prev, now, np.full((2, 2), 2.0), 60.0)
    np.testing.assert_allclose(speed[0], [0.0, 0.0])  # both feet of that pose restart
    want = SPEED_SMOOTHING * 2.0 + (1 - SPEED_SMOOTHING) * (MAX_STEP_M_S - 0.1)
    np.testing.assert_allclose(speed[1], [want, want])


def test_a_toe_is_lifted_to_its_speeds_clearance_and_no_further() -> None:
    lift = clearance_lift(_pose((0.0, 0.0)), np.array([[0.0, 2.25]]))
    np.testing.assert_allclose(lift, [[CLEARANCE_M[0], CLEARANCE_M[SPEEDS_M_S.index(2.25)]]])
    # Already high enough, or within a millimetre: left alone.
    assert np.all(clearance_lift(_pose((0.2, CLEARANCE_M[0] - 5e-4)), np.zeros((1, 2))) == 0)
    # Far below the floor (a tracking space whose origin is at eye level), by the toe or
    # by the ankle (as the floor pass decides): left alone.
    deep = clearance_lift(_pose((-FLOOR_MAX_LIFT_M - 0.01, -0.05)), np.zeros((1, 2)))
    np.testing.assert_allclose(deep, [[0.0, CLEARANCE_M[0] + 0.05]])
    ankle_deep = _pose((0.0, 0.0))
    ankle_deep[0, int(Joint.LEFT_FOOT), 1] = -FLOOR_MAX_LIFT_M - 0.01
    np.testing.assert_allclose(
        clearance_lift(ankle_deep, np.zeros((1, 2))), [[0.0, CLEARANCE_M[0]]]
    )
