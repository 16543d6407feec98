"""Legs apart: a held foot gives way where the contact IK draws one leg into the other."""

from __future__ import annotations

import numpy as np
import pytest

from posecast.body.apart import MAX_OVERLAP_M, RADII_M, keep_apart, keep_apart_quat, overlap
from posecast.body.ik import apply_leg_ik
from posecast.geometry.fk import fk_mat
from posecast.geometry.rotations import axis_mat, mat2quat, mat2r6d, quat2mat
from posecast.skeleton import NUM_JOINTS, Joint, reference_offsets

LEFT = (Joint.LEFT_THIGH, Joint.LEFT_SHIN, Joint.LEFT_FOOT, Joint.LEFT_TOE)
RIGHT = (Joint.RIGHT_THIGH, Joint.RIGHT_SHIN, Joint.RIGHT_FOOT, Joint.RIGHT_TOE)


def stance(bend: float = 0.3) -> tuple[np.ndarray, np.ndarray]:
    """World rotations ``(1, 19, 3, 3)`` and positions ``(1, 19, 3)`` of the reference
    body, knees bent by ``bend`` radians: the network's own pose, legs apart."""
    local = np.broadcast_to(np.eye(3), (NUM_JOINTS, 3, 3)).copy()
    for thigh, shin in ((LEFT[0], LEFT[1]), (RIGHT[0], RIGHT[1])):
        local[thigh] = axis_mat("X", -bend)
        local[shin] = axis_mat("X", 2 * bend)
    wm, wp = fk_mat(local, np.array([0.0, 0.9, 0.0]), reference_offsets())
    return wm[None], wp[None]


def held_into_other_leg(towards: float) -> tuple[np.ndarray, ...]:
    """The network's pose, and the contact IK's: the left ankle held ``towards`` of the
    way across to the right ankle (the other leg swinging past a planted foot)."""
    net_mat, net_pos = stance()
    mat, pos = net_mat.copy(), net_pos.copy()
    la, ra = pos[:, LEFT[2]], pos[:, RIGHT[2]]
    target = np.stack([la + towards * (ra - la), ra], axis=1)
    apply_leg_ik(mat, pos, target, np.array([[True, False]]))
    return net_mat, net_pos, mat, pos


def brute_overlap(pos: np.ndarray) -> float:
    """The same measure by dense sampling of both segments of every pair."""
    s = np.linspace(0.0, 1.0, 401)
    worst = -np.inf
    for i in range(3):
        a = pos[LEFT[i]] + s[:, None] * (pos[LEFT[i + 1]] - pos[LEFT[i]])
        for k in range(3):
            b = pos[RIGHT[k]] + s[:, None] * (pos[RIGHT[k + 1]] - pos[RIGHT[k]])
            d = np.linalg.norm(a[:, None] - b[None], axis=-1).min()
            worst = max(worst, RADII_M[i] + RADII_M[k] - d)
    return float(worst)


def test_overlap_of_parallel_legs_is_the_radii_less_the_gap() -> None:
    """Two straight legs ``g`` apart: thighs (the widest capsules) overlap by
    ``0.10 - g``."""
    _, wp = stance(bend=0.0)
    gap = float(np.linalg.norm(wp[0, LEFT[0]] - wp[0, RIGHT[0]]))
    assert overlap(wp)[0] == pytest.approx(2 * RADII_M[0] - gap, abs=1e-9)


def test_overlap_matches_dense_sampling_on_random_legs() -> None:
    rng = np.random.default_rng(3)
    pos = rng.normal(scale=0.15, size=(40, NUM_JOINTS, 3))
    got = overlap(pos)
    want = np.array([brute_overlap(p) for p in pos])
    # Sampling finds a distance at most a step's half-length longer than the true one.
    assert np.all(got >= want - 1e-9)
    assert np.allclose(got, want, atol=2e-3)


def test_a_held_foot_in_the_other_leg_gives_way_just_as_far_as_needed() -> None:
    net_mat, net_pos, mat, pos = held_into_other_leg(0.8)
    # The IK put one leg into the other; the network's legs stood apart.
    assert overlap(pos)[0] > 0.03 > MAX_OVERLAP_M > overlap(net_pos)[0]
    before = pos.copy()
    moved = keep_apart(mat, pos, net_mat, net_pos)
    assert moved.tolist() == [True]
    assert overlap(pos)[0] <= MAX_OVERLAP_M + 1e-9
    # It gave way only partly: not all the way back to the network's ankle, and not
    # more than 2/256 of that way beyond the least that keeps the legs apart.
    la = LEFT[2]
    share = np.linalg.norm(pos[0, la] - before[0, la]) / np.linalg.norm(
        net_pos[0, la] - before[0, la]
    )
    assert 0.05 < share < 0.95
    less = before.copy()
    back = np.stack([before[:, la] + (share - 2 / 256) * (net_pos[:, la] - before[:, la])], 1)
    redo_mat, redo = net_mat.copy(), net_pos.copy()
    targets = np.concatenate([back, before[:, None, RIGHT[2]]], 1)
    apply_leg_ik(redo_mat, redo, targets, np.array([[True, False]]))
    less[0, list(LEFT)] = redo[0, list(LEFT)]
    assert overlap(less)[0] > MAX_OVERLAP_M
    # Bones keep their lengths; the right leg and the rest of the body do not move.
    for a, b in ((LEFT[0], LEFT[1]), (LEFT[1], LEFT[2]), (LEFT[2], LEFT[3])):
        assert np.linalg.norm(pos[0, b] - pos[0, a]) == pytest.approx(
            np.linalg.norm(net_pos[0, b] - net_pos[0, a]), abs=1e-9
        )
    still = [j for j in range(NUM_JOINTS) if j not in (LEFT[1], LEFT[2], LEFT[3])]
    assert np.array_equal(pos[0, still], before[0, still])
    # Rotations agree with positions: the thigh's bone points at the new knee.
    bone = mat[0, LEFT[0]] @ reference_offsets()[LEFT[1]]
    assert np.allclose(net_pos[0, LEFT[0]] + bone, pos[0, LEFT[1]], atol=1e-9)


def test_legs_that_do_not_meet_are_left_as_they_are() -> None:
    net_mat, net_pos, mat, pos = held_into_other_leg(0.2)
    assert overlap(pos)[0] <= MAX_OVERLAP_M
    before_pos, before_mat = pos.copy(), mat.copy()
    assert keep_apart(mat, pos, net_mat, net_pos).tolist() == [False]
    assert np.array_equal(pos, before_pos) and np.array_equal(mat, before_mat)


def test_the_network_own_overlap_is_allowed() -> None:
    """Legs the network itself put into each other deeper than the allowance may stay
    as deep as it put them: a held foot that leaves them less deep than that is left
    alone, one that takes them deeper gives way to the network's depth, no further."""
    net_mat, net_pos = stance()
    # The network's right leg swung across, its ankle 3 cm from the left one.
    across = np.stack([net_pos[:, LEFT[2]], net_pos[:, LEFT[2]] + [-0.03, 0.0, 0.0]], 1)
    apply_leg_ik(net_mat, net_pos, across, np.array([[False, True]]))
    own = float(overlap(net_pos)[0])
    assert own > MAX_OVERLAP_M + 0.01
    for shift, deeper in ((0.01, False), (-0.02, True)):  # held 1 cm out, or 2 cm in
        mat, pos = net_mat.copy(), net_pos.copy()
        target = np.stack([net_pos[:, LEFT[2]] + [shift, 0.0, 0.0], net_pos[:, RIGHT[2]]], 1)
        apply_leg_ik(mat, pos, target, np.array([[True, False]]))
        deep = float(overlap(pos)[0])
        assert (deep > own) is deeper and deep > MAX_OVERLAP_M
        before = pos.copy()
        assert keep_apart(mat, pos, net_mat, net_pos).tolist() == [deeper]
        if deeper:
            assert own - 1e-3 <= overlap(pos)[0] <= own + 1e-3
        else:
            assert np.array_equal(pos, before)


def test_a_free_leg_keeps_what_the_contact_ik_made_of_it() -> None:
    """Only held feet are solved again: a leg whose ankle the contact IK left where the
    network put it (its knee turned, say) stays as the contact IK left it."""
    net_mat, net_pos, mat, pos = held_into_other_leg(0.8)
    pos[0, RIGHT[1]] += [0.0, 0.0, 0.01]  # the contact IK's knee, not the network's
    free_before = pos[0, list(RIGHT)].copy()
    keep_apart(mat, pos, net_mat, net_pos)
    assert np.array_equal(pos[0, list(RIGHT)], free_before)


def test_random_crossings_end_apart_within_a_millimetre() -> None:
    """Random legs, one foot (some poses both) held most of the way into the other leg:
    each pose ends no deeper than the allowance (or the network's own depth) by more
    than a millimetre (the share's refinement is linear, the knee's path is not), its
    bones kept."""
    rng = np.random.default_rng(1)
    offsets = reference_offsets()
    checked = 0
    for _ in range(300):
        local = np.broadcast_to(np.eye(3), (NUM_JOINTS, 3, 3)).copy()
        for thigh, shin in ((LEFT[0], LEFT[1]), (RIGHT[0], RIGHT[1])):
            local[thigh] = axis_mat("X", -rng.uniform(0, 0.8)) @ axis_mat(
                "Z", rng.uniform(-0.2, 0.2)
            )
            local[shin] = axis_mat("X", rng.uniform(0, 1.2))
        wm, wp = fk_mat(local, np.array([0.0, 0.9, 0.0]), offsets)
        net_mat, net_pos = wm[None], wp[None]
        mat, pos = net_mat.copy(), net_pos.copy()
        side = int(rng.integers(2))
        mine, other = (LEFT, RIGHT) if side == 0 else (RIGHT, LEFT)
        target = np.stack([pos[:, LEFT[2]], pos[:, RIGHT[2]]], 1)
        near = pos[0, other[2]] + rng.normal(scale=0.05, size=3)
        target[0, side] = pos[0, mine[2]] + rng.uniform(0.5, 1.0) * (near - pos[0, mine[2]])
        held = np.zeros((1, 2), np.bool_)
        held[0, side] = True
        if rng.uniform() < 0.3:
            held[0, 1 - side] = True
            target[0, 1 - side] += rng.normal(scale=0.03, size=3)
        apply_leg_ik(mat, pos, target, held)
        allowed = max(float(overlap(net_pos)[0]), MAX_OVERLAP_M)
        if overlap(pos)[0] <= allowed:
            continue
        checked += 1
        keep_apart(mat, pos, net_mat, net_pos)
        assert overlap(pos)[0] <= allowed + 1e-3
        for a, b in zip(LEFT[:-1] + RIGHT[:-1], LEFT[1:] + RIGHT[1:], strict=True):
            bone = np.linalg.norm(pos[0, b] - pos[0, a])
            assert bone == pytest.approx(np.linalg.norm(net_pos[0, b] - net_pos[0, a]), abs=1e-9)
    assert checked > 50


def test_giving_way_is_continuous_as_the_foot_is_drawn_in() -> None:
    """Drawn in frame by frame, the shown ankle moves by small steps: no jump where the
    legs start to meet."""
    ankles = []
    for towards in np.linspace(0.0, 1.0, 101):
        net_mat, net_pos, mat, pos = held_into_other_leg(float(towards))
        keep_apart(mat, pos, net_mat, net_pos)
        ankles.append(pos[0, LEFT[2]])
    steps = np.linalg.norm(np.diff(np.array(ankles), axis=0), axis=-1)
    full = np.linalg.norm(net_pos[0, RIGHT[2]] - net_pos[0, LEFT[2]])
    assert steps.max() < 0.02 * full  # 1 % of the way a frame, never much more


def test_the_engine_step_reads_the_network_legs_from_the_decoder_output() -> None:
    """``keep_apart_quat`` (the pipeline's step) rebuilds the network's legs from the
    decoder's rotations and the pelvis (float32, as the engine holds them) and moves the
    shown poses like
    ``keep_apart`` on float64 arrays: a batch of three, the middle one crossing, the
    others untouched."""
    rows = [held_into_other_leg(t) for t in (0.1, 0.8, 0.2)]
    net_mat = np.concatenate([r[0] for r in rows])
    net_pos = np.concatenate([r[1] for r in rows])
    mat = np.concatenate([r[2] for r in rows])
    pos = np.concatenate([r[3] for r in rows])
    local = np.broadcast_to(np.eye(3), (NUM_JOINTS, 3, 3)).copy()
    for thigh, shin in ((LEFT[0], LEFT[1]), (RIGHT[0], RIGHT[1])):
        local[thigh], local[shin] = axis_mat("X", -0.3), axis_mat("X", 0.6)
    rot6d = np.repeat(mat2r6d(local[1:]).reshape(1, -1), 3, axis=0).astype(np.float32)
    wp, quats = pos.astype(np.float32), mat2quat(mat).astype(np.float32)
    before_wp, before_q = wp.copy(), quats.copy()
    root_mat, root_pos = net_mat[:, 0].astype(np.float32), net_pos[:, 0].astype(np.float32)
    keep_apart_quat(wp, quats, rot6d, root_mat, root_pos)
    assert keep_apart(mat, pos, net_mat, net_pos).tolist() == [False, True, False]
    assert np.allclose(wp, pos, atol=1e-4)
    assert np.allclose(quat2mat(quats.astype(np.float64)), mat, atol=1e-4)
    assert not np.allclose(wp[1], before_wp[1], atol=1e-3)
    for i in (0, 2):
        assert np.array_equal(wp[i], before_wp[i]) and np.array_equal(quats[i], before_q[i])
