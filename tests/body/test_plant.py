"""Planted toes (:mod:`posecast.body.plant`): a toe in predicted contact near the floor
slides no faster than the bound, trails the network's toe by at most the lag, and
returns onto its track at the catch-up speed once the foot lifts."""

from __future__ import annotations

import numpy as np

from posecast.body.batch_fk import fk32
from posecast.body.clearance import TOES
from posecast.body.plant import (
    CATCH_M_S,
    LOW_M,
    MAX_LAG_M,
    MAX_SPEED_M_S,
    plant_offsets,
    plant_toes,
)
from posecast.geometry.rotations import mat2quat

FPS = 60.0


def _glide(contact: float, steps: int, speed: float, y: float = 0.0) -> list[np.ndarray]:
    """The shown left toe's horizontal positions while the network's glides along x."""
    prev, off = np.zeros((1, 2, 2)), np.zeros((1, 2, 2))
    shown = []
    for t in range(steps):
        toes = np.zeros((1, 2, 2))
        toes[0, 0, 0] = speed * t / FPS
        new = plant_offsets(
            toes, np.full((1, 2), y), np.full((1, 2), contact), prev, off, np.array([t == 0]), FPS
        )
        off, prev = new, toes + new
        shown.append(prev[0, 0].copy())
    return shown


def test_a_planted_toe_slides_no_faster_than_the_bound_and_trails_at_most_the_lag() -> None:
    shown = np.array(_glide(0.9, 30, 2.0))
    network = 2.0 * np.arange(30) / FPS
    speeds = np.linalg.norm(np.diff(shown, axis=0), axis=-1) * FPS
    lag = network - shown[:, 0]
    assert lag.max() <= MAX_LAG_M + 1e-9
    # Until the lag is used up the toe moves at the bound, then with the network's toe.
    np.testing.assert_allclose(speeds[:2], MAX_SPEED_M_S)  # 1.7 cm more lag a frame
    np.testing.assert_allclose(speeds[4:], 2.0)
    np.testing.assert_allclose(lag[-5:], MAX_LAG_M)


def test_a_free_or_lifted_toe_follows_the_network() -> None:
    for contact, y in ((0.1, 0.0), (0.9, LOW_M + 0.01)):
        shown = np.array(_glide(contact, 10, 2.0, y))
        np.testing.assert_allclose(shown[:, 0], 2.0 * np.arange(10) / FPS, atol=1e-12)


def test_the_trail_is_taken_up_at_the_catch_up_speed_once_the_foot_lifts() -> None:
    toes, y = np.zeros((1, 2, 2)), np.zeros((1, 2))
    off = np.zeros((1, 2, 2))
    off[0, 0, 0] = -MAX_LAG_M  # the toe trails by the lag, the network's now at rest
    prev = toes + off
    new = plant_offsets(toes, y, np.zeros((1, 2)), prev, off, np.array([False]), FPS)
    np.testing.assert_allclose(new[0, 0, 0], -MAX_LAG_M + CATCH_M_S / FPS)
    # A jump of the whole body, or a first frame, drops the trail.
    jumped = toes + 1.0
    assert not plant_offsets(jumped, y, np.ones((1, 2)), prev, off, np.array([False]), FPS).any()
    assert not plant_offsets(toes, y, np.ones((1, 2)), prev, off, np.array([True]), FPS).any()


def test_plant_toes_moves_the_leg_so_the_toe_lands_where_planted() -> None:
    rot6d = np.zeros((1, 108), np.float32)
    rot6d[:, 0::6] = 1.0  # every joint at rest: (1, 0, 0), (0, 1, 0)
    rot6d[:, 4::6] = 1.0
    root_mat = np.eye(3, dtype=np.float32)[None]
    root_pos = np.array([[0.0, 0.95, 0.0]], np.float32)
    wm, wp = fk32(rot6d, root_mat, root_pos)
    assert wm is not None
    wp[:, :, 1] -= wp[:, TOES, 1].min()  # toes on the floor
    quat = mat2quat(wm).astype(np.float32)
    toes = wp[:, TOES][:, :, [0, 2]].astype(np.float64)
    prev = toes.copy()
    prev[0, 0, 0] -= 0.03  # the left toe was shown 3 cm behind: it is asked to slide 1.8 m/s
    off = np.zeros((1, 2, 2))
    before, want = wp.copy(), prev[0, 0, 0] + MAX_SPEED_M_S / FPS
    plant_toes(wp, quat, np.ones((1, 2), np.float32), prev, off, np.array([False]), FPS)
    left = wp[0, TOES[0], [0, 2]]
    np.testing.assert_allclose(left[0], want, atol=1e-5)
    np.testing.assert_allclose(wp[0, TOES[1]], before[0, TOES[1]])  # the right toe stayed
    np.testing.assert_allclose(prev[0, 0], left, atol=1e-5)  # the state moved on
    # Bone lengths kept.
    from posecast.body.ik import LEGS

    for a, b in zip(LEGS[0][:-1], LEGS[0][1:], strict=True):
        np.testing.assert_allclose(
            np.linalg.norm(wp[0, a] - wp[0, b]),
            np.linalg.norm(before[0, a] - before[0, b]),
            atol=1e-5,
        )
