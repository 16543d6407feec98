"""Foot-contact IK (paper Sec. 3.1 post-processing): two-bone solve, lock, release."""

from __future__ import annotations

import numpy as np
import pytest

from posecast.body.ik import (
    FLOOR_MAX_LIFT_M,
    ContactIK,
    apply_leg_ik,
    floor_ik,
    floor_lift,
    sunk,
    two_bone_ik,
)
from posecast.geometry.fk import fk_mat
from posecast.geometry.rotations import axis_mat, normalize
from posecast.skeleton import NUM_JOINTS, Joint, reference_offsets

L_THIGH, L_SHIN, L_FOOT, L_TOE = Joint.LEFT_THIGH, Joint.LEFT_SHIN, Joint.LEFT_FOOT, Joint.LEFT_TOE
LEG_LENGTH_M = 0.43 + 0.42  # thigh + shin of the reference body
MM = 1e-3


def crouch(k: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
    """World rotations ``(1, 19, 3, 3)`` and positions ``(1, 19, 3)`` of the reference
    body with both knees bent. ``k`` (frames) drifts it the way a network's output
    slides: the pelvis moves 5 mm forward and 3 mm left per frame, and the left thigh
    swings forward 0.01 rad per frame, so the network's left ankle moves every frame."""
    local = np.broadcast_to(np.eye(3), (NUM_JOINTS, 3, 3)).copy()
    for thigh, shin in ((L_THIGH, L_SHIN), (Joint.RIGHT_THIGH, Joint.RIGHT_SHIN)):
        local[thigh] = axis_mat("X", -0.6 - (0.01 * k if thigh == L_THIGH else 0.0))
        local[shin] = axis_mat("X", 1.1)
    root = np.array([0.003 * k, 0.80, 0.005 * k])
    wm, wp = fk_mat(local, root, reference_offsets())
    return wm[None], wp[None]


def left_ankle(wp: np.ndarray) -> np.ndarray:
    return wp[0, L_FOOT]


def contact(left: float, right: float = 0.0) -> np.ndarray:
    return np.array([[left, right]])


def assert_leg_is_rigid(wm: np.ndarray, wp: np.ndarray) -> None:
    """Positions follow from rotations along both legs, so bone lengths are the reference
    ones and the rotations the IK wrote agree with the positions it wrote."""
    off = reference_offsets()
    for thigh, shin, foot, toe in (
        (L_THIGH, L_SHIN, L_FOOT, L_TOE),
        (Joint.RIGHT_THIGH, Joint.RIGHT_SHIN, Joint.RIGHT_FOOT, Joint.RIGHT_TOE),
    ):
        for parent, child in ((thigh, shin), (shin, foot), (foot, toe)):
            expected = wp[0, parent] + wm[0, parent] @ off[child]
            np.testing.assert_allclose(wp[0, child], expected, atol=1e-9)


# --- two_bone_ik ------------------------------------------------------------------------


def random_legs(rng: np.random.Generator, n: int) -> tuple[np.ndarray, ...]:
    hip = rng.normal(size=(n, 3))
    l1 = rng.uniform(0.3, 0.5, size=(n, 1))
    l2 = rng.uniform(0.3, 0.5, size=(n, 1))
    knee = hip + l1 * normalize(rng.normal(size=(n, 3)))
    ankle = knee + l2 * normalize(rng.normal(size=(n, 3)))
    return hip, knee, ankle, l1[:, 0], l2[:, 0]


def test_two_bone_ik_reaches_reachable_targets_and_keeps_bone_lengths(
    rng: np.random.Generator,
) -> None:
    hip, knee, ankle, l1, l2 = random_legs(rng, 200)
    d = rng.uniform(np.abs(l1 - l2) + 0.01, l1 + l2 - 0.01)
    target = hip + d[:, None] * normalize(rng.normal(size=(200, 3)))
    k2, a2 = two_bone_ik(hip, knee, ankle, target)
    np.testing.assert_allclose(a2, target, atol=1e-9)
    np.testing.assert_allclose(np.linalg.norm(k2 - hip, axis=-1), l1, atol=1e-9)
    np.testing.assert_allclose(np.linalg.norm(a2 - k2, axis=-1), l2, atol=1e-9)
    # The knee stays in the plane of hip, target and old knee, on the old knee's side.
    u = normalize(target - hip)
    normal = np.cross(u, knee - hip)
    np.testing.assert_allclose(np.sum(normal * (k2 - hip), axis=-1), 0.0, atol=1e-9)
    old_bend = (knee - hip) - np.sum((knee - hip) * u, -1, keepdims=True) * u
    assert np.all(np.sum(old_bend * (k2 - hip), axis=-1) > 0.0)


def test_two_bone_ik_reaches_toward_unreachable_targets(rng: np.random.Generator) -> None:
    hip, knee, ankle, l1, l2 = random_legs(rng, 50)
    direction = normalize(rng.normal(size=(50, 3)))
    target = hip + 2.0 * (l1 + l2)[:, None] * direction
    k2, a2 = two_bone_ik(hip, knee, ankle, target)
    np.testing.assert_allclose(a2, hip + (l1 + l2)[:, None] * direction, atol=1e-5)
    np.testing.assert_allclose(np.linalg.norm(k2 - hip, axis=-1), l1, atol=1e-9)
    np.testing.assert_allclose(np.linalg.norm(a2 - k2, axis=-1), l2, atol=1e-5)


def test_two_bone_ik_bends_a_straight_leg_forward() -> None:
    """A straight leg has no bend plane; a closer target bends the knee toward +Z."""
    hip = np.array([[0.0, 1.0, 0.0]])
    knee, ankle = hip - [0.0, 0.43, 0.0], hip - [0.0, 0.85, 0.0]
    k2, a2 = two_bone_ik(hip, knee, ankle, hip - [0.0, 0.7, 0.0])
    np.testing.assert_allclose(a2, hip - [0.0, 0.7, 0.0], atol=1e-12)
    assert k2[0, 2] > 0.1
    assert k2[0, 0] == pytest.approx(0.0, abs=1e-12)


def test_apply_leg_ik_moves_only_the_active_leg() -> None:
    wm, wp = crouch()
    before_m, before_p = wm.copy(), wp.copy()
    targets = wp[:, [L_FOOT, Joint.RIGHT_FOOT]] + np.array([0.05, 0.02, -0.04])
    apply_leg_ik(wm, wp, targets, np.array([[True, False]]))
    np.testing.assert_allclose(left_ankle(wp), targets[0, 0], atol=1e-9)
    # The foot keeps its world rotation and the toe rides along with the ankle.
    np.testing.assert_allclose(wm[0, L_FOOT], before_m[0, L_FOOT])
    np.testing.assert_allclose(
        wp[0, L_TOE] - wp[0, L_FOOT], before_p[0, L_TOE] - before_p[0, L_FOOT], atol=1e-12
    )
    untouched = [j for j in Joint if j not in (L_SHIN, L_FOOT, L_TOE)]
    np.testing.assert_array_equal(wp[0, untouched], before_p[0, untouched])
    assert_leg_is_rigid(wm, wp)


# --- ContactIK ----------------------------------------------------------------------------


def test_locked_foot_stays_within_a_millimetre_while_contact_holds() -> None:
    """Contact stays above 0.5 for 30 frames while the network's ankle drifts 37 cm,
    always within the leg's reach: the shown ankle stays where the contact began (the
    paper's rule; the early release on large drift is switched off here)."""
    ik = ContactIK.zeros(1, release_frames=4, max_drift_m=None)
    wm, wp = crouch(0)
    lock = left_ankle(wp).copy()
    ik.step(wm, wp, contact(0.9))
    np.testing.assert_allclose(left_ankle(wp), lock, atol=1e-12)  # locking moves nothing
    drift = []
    for k in range(1, 31):
        wm, wp = crouch(k)
        drift.append(np.linalg.norm(left_ankle(wp) - lock))
        assert np.linalg.norm(lock - wp[0, L_THIGH]) < LEG_LENGTH_M - 0.01  # reachable
        net_right = wp[0, Joint.RIGHT_FOOT].copy()
        ik.step(wm, wp, contact(0.51 + 0.4 * (k % 2)))
        assert np.linalg.norm(left_ankle(wp) - lock) < MM
        np.testing.assert_array_equal(wp[0, Joint.RIGHT_FOOT], net_right)  # no contact
        assert_leg_is_rigid(wm, wp)
    assert max(drift) > 0.3  # the network really slid


def test_release_blends_back_linearly_over_release_frames() -> None:
    """Contact ends on frame 0 of the release: the shown ankle then moves in equal steps
    from the lock to the network's ankle, weights ``1, 3/4, 1/2, 1/4`` of the lock for
    ``release_frames = 4``, and from the 5th frame on shows the network's own pose."""
    R = 4
    ik = ContactIK.zeros(1, release_frames=R)
    wm, wp = crouch(0)
    lock = left_ankle(wp).copy()
    ik.step(wm, wp, contact(0.9))
    wm_net, wp_net = crouch(8)  # the network's pose, held still during the release
    net = left_ankle(wp_net).copy()
    assert np.linalg.norm(net - lock) > 0.05
    for i in range(R + 3):
        wm, wp = wm_net.copy(), wp_net.copy()
        ik.step(wm, wp, contact(0.2))
        w = max(0.0, 1.0 - i / R)
        np.testing.assert_allclose(left_ankle(wp), w * lock + (1 - w) * net, atol=1e-9)
        assert_leg_is_rigid(wm, wp)
    np.testing.assert_array_equal(wp, wp_net)
    np.testing.assert_array_equal(wm, wm_net)
    assert not ik.locked.any()
    assert not ik.release_left.any()


def test_foot_landing_again_mid_release_does_not_pop() -> None:
    """Contact flickers (0.9, then 0.4 for two frames, then 0.6): when the foot lands
    again halfway through its release it locks where it is shown, so the shown ankle
    never moves by more than one release step (a quarter of the lock-to-network gap)."""
    R = 4
    # No early release for drift: the lock-to-network gap here (crouch 0 to 10) is
    # beyond the default's, and this is about the flicker alone.
    ik = ContactIK.zeros(1, release_frames=R, max_drift_m=None)
    wm, wp = crouch(0)
    ik.step(wm, wp, contact(0.9))
    wm_net, wp_net = crouch(10)
    gap = np.linalg.norm(left_ankle(wp_net) - left_ankle(wp))
    assert gap > 0.05
    shown = [left_ankle(wp).copy()]
    for c in (0.4, 0.4, 0.6, 0.6, 0.6):
        wm, wp = wm_net.copy(), wp_net.copy()
        ik.step(wm, wp, contact(c))
        shown.append(left_ankle(wp).copy())
    steps = np.linalg.norm(np.diff(shown, axis=0), axis=-1)
    assert steps.max() <= gap / R + 1e-9
    # Locked again: held still from the landing on.
    np.testing.assert_allclose(shown[3], shown[5], atol=MM)


def test_contact_ik_works_on_views_of_engine_buffers() -> None:
    """The engine hands in reshaped views of its slot arrays; steps update them in place."""
    locked = np.zeros((2, 3, 2), bool)
    lock_pos = np.zeros((2, 3, 2, 3))
    release = np.zeros((2, 3, 2), np.int64)
    ik = ContactIK(locked.reshape(6, 2), lock_pos.reshape(6, 2, 3), release.reshape(6, 2), 4)
    wm, wp = crouch(0)
    wm6, wp6 = np.repeat(wm, 6, axis=0), np.repeat(wp, 6, axis=0)
    prob = np.zeros((6, 2))
    prob[4] = [0.9, 0.0]
    ik.step(wm6, wp6, prob)
    assert locked[1, 1, 0] and locked.sum() == 1
    np.testing.assert_allclose(lock_pos[1, 1, 0], left_ankle(wp))
    prob[4] = [0.1, 0.0]
    ik.step(wm6, wp6, prob)
    assert not locked.any()
    assert release[1, 1, 0] == 3  # one release frame shown, three to go


def test_a_lock_the_network_drifted_far_from_is_released_and_the_foot_steps() -> None:
    """With ``max_drift_m = 0.2`` the lock holds (within 1 mm) until the network's ankle
    is over 20 cm away, is then released and blends back over ``release_frames``; a
    contact still predicted then locks again where the foot is (a step), and holds."""
    ik = ContactIK.zeros(1, release_frames=4, max_drift_m=0.2)
    wm, wp = crouch(0)
    lock = left_ankle(wp).copy()
    ik.step(wm, wp, contact(0.9))
    released_at = None
    for k in range(1, 31):
        wm, wp = crouch(k)
        drift = float(np.linalg.norm(left_ankle(wp) - lock))
        ik.step(wm, wp, contact(0.9))
        if drift <= 0.2:
            assert released_at is None
            assert np.linalg.norm(left_ankle(wp) - lock) < MM
        elif released_at is None:
            released_at = k
            assert not ik.locked[0, 0] and ik.release_left[0, 0] == 3
        if released_at is not None and k == released_at + 3:
            assert not ik.locked[0, 0] and ik.release_left[0, 0] == 0  # the last blend
        if released_at is not None and k == released_at + 4:
            assert ik.locked[0, 0]  # still predicted: a new lock, at the network's ankle
            relock = left_ankle(wp).copy()
            np.testing.assert_allclose(relock, left_ankle(crouch(k)[1]), atol=1e-9)
        if released_at is not None and k > released_at + 4:
            assert np.linalg.norm(left_ankle(wp) - relock) < MM  # and it holds there
    assert released_at is not None and released_at + 4 < 30


def test_a_hint_bends_a_straight_leg_its_way_whatever_the_rounding(
    rng: np.random.Generator,
) -> None:
    """A leg straight up to rounding (knee off the line by a micrometre-scale excess,
    pointing anywhere) bends toward the hint; a leg bent by more than ``hint_m`` keeps
    its own plane."""
    hip, target = np.array([[0.0, 0.9, 0.0]]), np.array([[0.0, 0.2, 0.0]])
    hint = np.array([[0.0, 0.0, 1.0]])
    knees = []
    for _ in range(20):
        side = normalize(np.array([[rng.normal(), 0.0, rng.normal()]]))
        knee = hip + [0.0, -0.43, 0.0] + 7e-4 * side  # 0.7 mm off: rounding, any way
        ankle = knee + 0.42 * normalize(np.array([[0.0, -0.85, 0.0]]) + hip - knee)
        k2, a2 = two_bone_ik(hip, knee, ankle, target, hint, 0.05)
        np.testing.assert_allclose(a2, target, atol=1e-9)
        knees.append(k2[0])
    spread = np.ptp(np.array(knees), axis=0)
    assert spread.max() < 1e-3, spread  # the same knee, to a millimetre, every time
    assert knees[0][2] > 0.1  # forward, along the hint
    bent_knee = np.array([[0.1, 0.5, 0.0]])  # 10 cm to the side: its own plane wins
    bent_ankle = bent_knee + 0.42 * normalize(np.array([[0.0, 0.1, 0.0]]) - bent_knee)
    k2, _ = two_bone_ik(hip, bent_knee, bent_ankle, target, hint, 0.05)
    k_ref, _ = two_bone_ik(hip, bent_knee, bent_ankle, target)
    np.testing.assert_allclose(k2, k_ref, atol=1e-12)


# --- floor_ik -------------------------------------------------------------------------


def lowest(wp: np.ndarray, foot: Joint, toe: Joint) -> float:
    return float(min(wp[0, foot, 1], wp[0, toe, 1]))


@pytest.mark.parametrize("depth_m", [0.005, 0.05, 0.12])
def test_floor_ik_puts_a_sunken_foot_on_the_floor_and_keeps_the_leg_rigid(depth_m: float) -> None:
    wm, wp = crouch()
    wm, wp = wm.copy(), wp.copy()
    wp[..., 1] -= lowest(wp, L_FOOT, L_TOE) + depth_m  # the whole body sunk below y = 0
    wp[0, Joint.RIGHT_THIGH :, 1] += 0.5  # the right leg well above it
    right_before = wp[0, Joint.RIGHT_THIGH :].copy()
    pelvis_before, foot_rot = wp[0, Joint.PELVIS].copy(), wm[0, L_FOOT].copy()
    assert lowest(wp, L_FOOT, L_TOE) == pytest.approx(-depth_m)
    lifted = floor_ik(wm, wp)
    assert lifted.tolist() == [[True, False]]
    assert lowest(wp, L_FOOT, L_TOE) == pytest.approx(0.0, abs=1e-6)
    np.testing.assert_allclose(wm[0, L_FOOT], foot_rot)  # the foot keeps its rotation
    np.testing.assert_array_equal(wp[0, Joint.PELVIS], pelvis_before)
    np.testing.assert_array_equal(wp[0, Joint.RIGHT_THIGH :], right_before)
    # Only the sunken leg moved, its bones still rigid: move the right leg back to its
    # FK place and check both legs against the rotations.
    wp[0, Joint.RIGHT_THIGH :, 1] -= 0.5
    assert_leg_is_rigid(wm, wp)


def test_floor_ik_leaves_feet_on_or_above_the_floor_and_far_below_it_alone() -> None:
    wm, wp = crouch()
    wp = wp - np.array([0.0, lowest(wp, L_FOOT, L_TOE), 0.0])  # the lower foot exactly on y = 0
    for shift in (0.0, 0.3, -(FLOOR_MAX_LIFT_M + 0.01), -1.5):  # -1.5: an eye-level origin
        m, p = wm.copy(), wp + np.array([0.0, shift, 0.0])
        before = p.copy()
        assert not floor_ik(m, p).any(), shift
        np.testing.assert_array_equal(p, before)
        np.testing.assert_array_equal(m, wm)
    assert floor_lift(wp - np.array([0.0, 0.01, 0.0])) == pytest.approx(np.array([[0.01, 0.01]]))


def test_floor_ik_bends_a_straight_leg_to_lift_its_foot() -> None:
    """A straight leg whose pelvis is too low for the floor: the knee bends (forward, as
    two_bone_ik bends a straight leg) and the foot ends on the floor, bones kept."""
    straight = np.broadcast_to(np.eye(3), (NUM_JOINTS, 3, 3))
    wm, wp = fk_mat(straight, np.array([0.0, 1.0, 0.0]), reference_offsets())
    wm, wp = wm[None].copy(), wp[None].copy()
    wp[..., 1] -= lowest(wp, L_FOOT, L_TOE) + 0.08
    floor_ik(wm, wp)
    assert lowest(wp, L_FOOT, L_TOE) == pytest.approx(0.0, abs=1e-6)
    assert wp[0, Joint.LEFT_SHIN, 2] > wp[0, Joint.LEFT_THIGH, 2]  # the knee went forward
    assert_leg_is_rigid(wm, wp)


def test_sunk_is_a_foot_deeper_than_the_floor_pass_lifts() -> None:
    """``sunk`` says which poses the floor pass leaves under the floor: a foot (the lower
    of ankle and toe) more than ``FLOOR_MAX_LIFT_M`` down, on any batch shape."""
    wm, wp = crouch()
    wp = wp - np.array([0.0, lowest(wp, L_FOOT, L_TOE), 0.0])  # the lower foot on y = 0
    depths = (0.0, -0.3, 0.1, FLOOR_MAX_LIFT_M - 0.01, FLOOR_MAX_LIFT_M + 0.01, 1.5)
    poses = np.stack([wp[0] - np.array([0.0, d, 0.0]) for d in depths])  # (6, 19, 3)
    assert sunk(poses).tolist() == [False, False, False, False, True, True]
    # One foot is enough: the right leg alone pushed down 0.5 m.
    one = wp.copy()
    one[0, Joint.RIGHT_FOOT :, 1] -= FLOOR_MAX_LIFT_M + 0.1
    assert sunk(one).tolist() == [True]
    assert sunk(poses.reshape(2, 3, NUM_JOINTS, 3)).tolist() == [[False] * 3, [False, True, True]]
    # What sunk calls too deep, floor_ik leaves alone; what it does not, floor_ik lifts.
    for d, deep in zip(depths[2:5], (False, False, True), strict=True):
        m, p = wm.copy(), wp - np.array([0.0, d, 0.0])
        assert bool(floor_ik(m, p).any()) is not deep, d


def hyperextended_leg(rad: float = -0.1) -> tuple[np.ndarray, np.ndarray]:
    """World rotations and positions ``(1, 19, ...)`` of the reference body standing
    straight, its left knee bent ``rad`` the wrong way (backward, hyperextended)."""
    local = np.broadcast_to(np.eye(3), (NUM_JOINTS, 3, 3)).copy()
    local[L_SHIN] = axis_mat("X", rad)
    wm, wp = fk_mat(local, np.array([0.0, 0.9, 0.0]), reference_offsets())
    return wm[None].copy(), wp[None].copy()


def knee_ahead_m(wp: np.ndarray) -> float:
    """How far the left knee is in front (+Z) of its hip-ankle line, metres."""
    hip, knee, ankle = wp[0, L_THIGH], wp[0, L_SHIN], wp[0, L_FOOT]
    u = (ankle - hip) / np.linalg.norm(ankle - hip)
    off = (knee - hip) - np.dot(knee - hip, u) * u
    return float(off[2])


@pytest.mark.parametrize("rad", [-0.1, -0.02])
def test_a_knee_drawn_in_bends_forward_even_from_a_hyperextended_leg(rad: float) -> None:
    """A locked foot 15 cm nearer the hip than a slightly hyperextended leg reaches: the
    shown pose (rotations given) bends the knee forward, the way a knee bends, with
    bone lengths kept and the knee's offset mirrored (as far in front as it was
    behind, before the bend the reach adds); the candidate pool (positions only) keeps
    the leg's own plane, so its knee goes further back."""
    wm, wp = hyperextended_leg(rad)
    assert knee_ahead_m(wp) < 0.0  # behind the line: hyperextended
    target = wp[:, [L_FOOT, Joint.RIGHT_FOOT]].copy()
    target[0, 0, 1] += 0.15
    active = np.array([[True, False]])
    shown_m, shown_p = wm.copy(), wp.copy()
    apply_leg_ik(shown_m, shown_p, target, active)
    pool_p = wp.copy()
    apply_leg_ik(None, pool_p, target, active)
    np.testing.assert_allclose(shown_p[0, L_FOOT], target[0, 0], atol=1e-9)
    np.testing.assert_allclose(pool_p[0, L_FOOT], target[0, 0], atol=1e-9)
    assert knee_ahead_m(shown_p) > 0.1  # bent forward by the reach
    assert knee_ahead_m(pool_p) < -0.1  # the same bend, backward
    np.testing.assert_allclose(knee_ahead_m(shown_p), -knee_ahead_m(pool_p), atol=1e-9)
    assert_leg_is_rigid(shown_m, shown_p)
    # A leg already bent forward is bent as it was, with or without rotations.
    wm, wp = hyperextended_leg(-rad)
    target = wp[:, [L_FOOT, Joint.RIGHT_FOOT]].copy()
    target[0, 0, 1] += 0.15
    a, b = wp.copy(), wp.copy()
    apply_leg_ik(wm.copy(), a, target, active)
    apply_leg_ik(None, b, target, active)
    np.testing.assert_allclose(a, b, atol=1e-12)
