"""The upper-body pass (:mod:`posecast.body.upper_ik`): head and hands on their
trackers, bones unchanged, rotations FK-consistent, no elbow flips, out-of-reach
targets reached for and flagged; a guessed pelvis's reach and lean. The engine
streaming it: ``tests/online/engine/test_shown.py``."""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
import pytest

from posecast.body.upper_ik import (
    ARM_REACH_M,
    HAND_REACH_SOFTNESS_M,
    LEAN_MOST_RAD,
    LEAN_SHARE,
    NECK_SHARE,
    REACH_EASE,
    REACH_JOINTS,
    SPINE_REACH_M,
    WRIST_ELBOW_SHARE,
    ease_reach,
    ease_reach_clip,
    lean_root,
    reach_root,
    reach_shift,
    solve_upper_body,
    turn_pelvis,
)
from posecast.geometry.fk import fk_mat, world2local_mat
from posecast.geometry.rotations import aa2mat, mat2aa, mat2quat, mat2r6d, quat2mat
from posecast.offline.evaluation.reconstruct import pose_from_rotations
from posecast.online.engine.types import TrackerFrame
from posecast.skeleton import LOWER_BODY, PARENTS, Joint, reference_offsets
from posecast.tracking.features import TrackerSlot

WalkFrames = Callable[..., list[TrackerFrame]]
HANDS = ((Joint.LEFT_HAND, TrackerSlot.LEFT_HAND), (Joint.RIGHT_HAND, TrackerSlot.RIGHT_HAND))
ARMS = (
    (Joint.LEFT_UPPER_ARM, Joint.LEFT_FOREARM, TrackerSlot.LEFT_HAND),
    (Joint.RIGHT_UPPER_ARM, Joint.RIGHT_FOREARM, TrackerSlot.RIGHT_HAND),
)
BONES = np.linalg.norm(reference_offsets(), axis=-1)


def random_poses(E: int, seed: int, straight_wrists: bool = False) -> tuple[np.ndarray, np.ndarray]:
    """``E`` poses of the reference body: world positions ``(E, 19, 3)`` and quats
    ``(E, 19, 4)``; small random local rotations, elbows bent 90-115 degrees so the
    hands are well inside the arms' reach (``straight_wrists``: the hands' local
    rotations the identity)."""
    rng = np.random.default_rng(seed)
    local = aa2mat(rng.normal(0.0, 0.25, (E, 19, 3)))
    if straight_wrists:
        local[:, [Joint.LEFT_HAND, Joint.RIGHT_HAND]] = np.eye(3)
    local[:, 0] = aa2mat(rng.normal(0.0, 0.1, (E, 3)))
    for fore, sign in ((Joint.LEFT_FOREARM, -1.0), (Joint.RIGHT_FOREARM, 1.0)):
        bend = np.zeros((E, 3))
        bend[:, 1] = sign * rng.uniform(1.6, 2.0, E)  # about +-Y: the forearm turns forward
        local[:, fore] = local[:, fore] @ aa2mat(bend)
    root = np.array([0.0, 0.98, 0.0]) + rng.normal(0.0, 0.05, (E, 3))
    wm, wp = fk_mat(local, root, reference_offsets())
    return wp, mat2quat(wm)


def trackers(pos: np.ndarray, shift: np.ndarray, quat: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Trackers on the joints of ``pos`` moved by ``shift (E, 4, 3)``, orientations ``quat``."""
    tp = pos[:, [Joint.HEAD, Joint.LEFT_HAND, Joint.RIGHT_HAND, Joint.PELVIS]] + shift
    return tp, quat


def reachable_head(pos: np.ndarray, seed: int) -> np.ndarray:
    """Headset positions ``(E, 3)`` the spine chain can reach: the network's head turned
    about the spine joint by a few degrees, and 0-10 % nearer (at most 0.51 m of 0.52)."""
    rng = np.random.default_rng(seed)
    v = pos[:, Joint.HEAD] - pos[:, Joint.SPINE]
    v = np.einsum("eab,eb->ea", aa2mat(rng.normal(0.0, 0.1, (len(pos), 3))), v)
    n = np.linalg.norm(v, axis=-1, keepdims=True)
    length = np.minimum(n * rng.uniform(0.9, 1.0, (len(pos), 1)), 0.51)
    out: np.ndarray = pos[:, Joint.SPINE] + v / n * length
    return out


def random_quats(E: int, seed: int) -> np.ndarray:
    return mat2quat(aa2mat(np.random.default_rng(seed).normal(0.0, 1.0, (E, 4, 3))))


def assert_fk_consistent(pos: np.ndarray, quat: np.ndarray, atol: float = 1e-5) -> None:
    """FK of the local rotations (``parent^T world``) gives back the positions."""
    wm = quat2mat(quat.astype(np.float64))
    local = world2local_mat(wm)
    _, again = fk_mat(local, pos[:, 0].astype(np.float64), reference_offsets())
    np.testing.assert_allclose(again, pos, atol=atol)


def assert_bones_kept(pos: np.ndarray, atol: float = 1e-6) -> None:
    p = pos.astype(np.float64)
    for j, parent in enumerate(PARENTS):
        if parent >= 0:
            length = np.linalg.norm(p[:, j] - p[:, parent], axis=-1)
            np.testing.assert_allclose(length, BONES[j], atol=atol, err_msg=Joint(j).name)


def test_reachable_targets_are_hit_with_bones_and_fk_kept() -> None:
    E = 64
    pos, quat = random_poses(E, seed=0)
    shift = np.random.default_rng(1).uniform(-0.05, 0.05, (E, 4, 3))
    tp, tq = trackers(pos, shift, random_quats(E, seed=2))
    tp[:, TrackerSlot.HEAD] = reachable_head(pos, seed=3)
    out_pos, out_quat, limited = solve_upper_body(pos, quat, tp, tq)
    assert out_pos.dtype == np.float32 and out_quat.dtype == np.float32
    assert not limited.any()
    np.testing.assert_array_less(
        np.linalg.norm(out_pos[:, Joint.HEAD] - tp[:, TrackerSlot.HEAD], axis=-1), 1e-3
    )
    for joint, slot in HANDS:
        np.testing.assert_array_less(np.linalg.norm(out_pos[:, joint] - tp[:, slot], axis=-1), 1e-3)
    assert_bones_kept(out_pos)
    assert_fk_consistent(out_pos, out_quat)
    # The effectors' world rotations are the trackers'.
    for joint, slot in ((Joint.HEAD, TrackerSlot.HEAD), *HANDS):
        np.testing.assert_allclose(
            quat2mat(out_quat[:, joint].astype(np.float64)), quat2mat(tq[:, slot]), atol=1e-6
        )
    # Pelvis and legs are not the pass's.
    legs = [int(Joint.PELVIS), *(int(j) for j in LOWER_BODY)]
    np.testing.assert_allclose(out_pos[:, legs], pos[:, legs], atol=1e-6)
    np.testing.assert_array_equal(out_quat[:, legs], quat[:, legs].astype(np.float32))


def test_targets_already_met_change_nothing() -> None:
    """Trackers where the pose has its head and hands: with straight wrists (where the
    controllers' rotations put the elbows too) nothing changes; with bent ones nothing
    changes when the elbows are the network's alone (``wrist_share=0``)."""
    for straight, share in ((True, WRIST_ELBOW_SHARE), (True, 1.0), (False, 0.0)):
        pos, quat = random_poses(8, seed=3, straight_wrists=straight)
        tp, _ = trackers(pos, np.zeros((8, 4, 3)), quat)
        tq = quat[:, [Joint.HEAD, Joint.LEFT_HAND, Joint.RIGHT_HAND, Joint.PELVIS]]
        out_pos, out_quat, limited = solve_upper_body(pos, quat, tp, tq, wrist_share=share)
        assert not limited.any()
        np.testing.assert_allclose(out_pos, pos, atol=1e-6)
        np.testing.assert_allclose(quat2mat(out_quat.astype(np.float64)), quat2mat(quat), atol=1e-6)


def test_the_elbow_follows_the_controllers_rotation() -> None:
    """The true pose has straight wrists; the network's has each upper arm swung 40
    degrees about the shoulder-hand line (the hand where it was, the elbow elsewhere).
    With the controllers on the true hands: ``wrist_share=1`` puts the elbows back on
    the true ones, ``0`` leaves the network's, and the default lands between, nearer
    the truth; the hands are on the controllers every time."""
    E = 16
    true_pos, true_quat = random_poses(E, seed=11, straight_wrists=True)
    pos, mats = true_pos.copy(), quat2mat(true_quat)
    for upper, fore, _ in ARMS:
        axis = pos[:, fore + 1] - pos[:, upper]
        axis /= np.linalg.norm(axis, axis=-1, keepdims=True)
        R = aa2mat(axis * np.radians(40.0))
        for j in (fore, fore + 1):
            pos[:, j] = pos[:, upper] + np.einsum("eab,eb->ea", R, pos[:, j] - pos[:, upper])
        for j in (upper, fore):  # the hand keeps its world rotation: its wrist now bends
            mats[:, j] = R @ mats[:, j]
    quat = mat2quat(mats)
    assert_fk_consistent(pos, quat)
    tp, _ = trackers(true_pos, np.zeros((E, 4, 3)), true_quat)
    tq = true_quat[:, [Joint.HEAD, Joint.LEFT_HAND, Joint.RIGHT_HAND, Joint.PELVIS]]

    def elbow_error(share: float) -> np.ndarray:
        out_pos, out_quat, limited = solve_upper_body(pos, quat, tp, tq, wrist_share=share)
        assert not limited.any()
        assert_bones_kept(out_pos)
        assert_fk_consistent(out_pos, out_quat)
        for joint, slot in HANDS:
            np.testing.assert_array_less(
                np.linalg.norm(out_pos[:, joint] - tp[:, slot], axis=-1), 1e-4
            )
        elbows = [int(Joint.LEFT_FOREARM), int(Joint.RIGHT_FOREARM)]
        err: np.ndarray = np.linalg.norm(out_pos[:, elbows] - true_pos[:, elbows], axis=-1)
        return err

    np.testing.assert_array_less(elbow_error(1.0), 1e-4)
    network = elbow_error(0.0)
    assert network.min() > 0.05  # 40 degrees of swivel is 6-20 cm at the elbow
    default = elbow_error(WRIST_ELBOW_SHARE)
    assert 0.0 < WRIST_ELBOW_SHARE < 1.0
    np.testing.assert_array_less(default, 0.6 * network)


def _angle(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Degrees between rotation matrices ``(..., 3, 3)``."""
    rel = np.swapaxes(a, -1, -2) @ b
    cos = np.clip((np.trace(rel, axis1=-2, axis2=-1) - 1.0) / 2.0, -1.0, 1.0)
    return np.degrees(np.arccos(cos))


def test_the_neck_takes_its_share_of_a_turn_of_the_head() -> None:
    """A headset turned 40 degrees about the neck's bone from where the network had the
    head (the head joint already on the headset): the head's world rotation becomes the
    headset's, nothing moves, and the neck turns with it by NECK_SHARE of the 40
    degrees about its bone, the head's rotation relative to the neck taking the rest."""
    pos, quat = random_poses(6, seed=8, straight_wrists=True)
    tp, _ = trackers(pos, np.zeros((6, 4, 3)), quat)
    mats = quat2mat(quat)
    bone = pos[:, Joint.HEAD] - pos[:, Joint.NECK]
    bone /= np.linalg.norm(bone, axis=-1, keepdims=True)
    turn = aa2mat(bone * np.radians(40.0))
    tq = quat[:, [Joint.HEAD, Joint.LEFT_HAND, Joint.RIGHT_HAND, Joint.PELVIS]].copy()
    tq[:, TrackerSlot.HEAD] = mat2quat(turn @ mats[:, Joint.HEAD])
    out_pos, out_quat, limited = solve_upper_body(pos, quat, tp, tq)
    assert not limited.any()
    np.testing.assert_allclose(out_pos, pos, atol=1e-6)
    out = quat2mat(out_quat.astype(np.float64))
    np.testing.assert_allclose(out[:, Joint.HEAD], quat2mat(tq[:, TrackerSlot.HEAD]), atol=1e-6)
    neck_turn = aa2mat(bone * np.radians(40.0 * NECK_SHARE))
    np.testing.assert_allclose(out[:, Joint.NECK], neck_turn @ mats[:, Joint.NECK], atol=1e-6)
    assert 0.3 < NECK_SHARE < 1.0
    others = [j for j in range(19) if j not in (Joint.NECK, Joint.HEAD)]
    np.testing.assert_allclose(out[:, others], mats[:, others], atol=1e-6)
    assert_fk_consistent(out_pos, out_quat)


def test_a_player_bending_over_curls_the_whole_chain() -> None:
    """The network's spine upright; the player curled forward (spine, chest and neck
    25, 25 and 15 degrees about +X) and the headset on that head, turned with it. Every
    joint of the chain ends within 8 degrees of the curl (1.0, 4.0, 7.8 and 4.8 for
    spine, chest, neck and head), the neck sharing the head's pitch: the solve before
    the lean and the neck's share (a swing for each bone, the head taking the headset's
    turn) left the neck straight, 15 degrees off, and the head 9.6."""
    E = 2
    upright = np.broadcast_to(np.eye(3), (E, 19, 3, 3)).copy()
    root = np.tile([0.0, 0.98, 0.0], (E, 1))
    wm, wp = fk_mat(upright, root, reference_offsets())
    curl = upright.copy()
    for joint, degrees in ((Joint.SPINE, 25.0), (Joint.CHEST, 25.0), (Joint.NECK, 15.0)):
        curl[:, joint] = aa2mat(np.tile([np.radians(degrees), 0.0, 0.0], (E, 1)))
    true_mat, true_pos = fk_mat(curl, root, reference_offsets())
    slots = [Joint.HEAD, Joint.LEFT_HAND, Joint.RIGHT_HAND, Joint.PELVIS]
    tp, tq = true_pos[:, slots], mat2quat(true_mat[:, slots])
    out_pos, out_quat, limited = solve_upper_body(wp, mat2quat(wm), tp, tq)
    assert not limited.any()
    out_local = world2local_mat(quat2mat(out_quat.astype(np.float64)))
    chain = [Joint.SPINE, Joint.CHEST, Joint.NECK, Joint.HEAD]
    assert (_angle(out_local[:, chain], curl[:, chain]) < 8.0).all()
    np.testing.assert_allclose(out_pos[:, Joint.HEAD], tp[:, TrackerSlot.HEAD], atol=1e-3)
    assert 0.5 <= LEAN_SHARE <= 1.0
    assert_fk_consistent(out_pos, out_quat)


def side(shoulder: np.ndarray, target: np.ndarray, elbow: np.ndarray) -> np.ndarray:
    """The elbow's offset from the shoulder-target line, perpendicular to it ``(E, 3)``."""
    u = target - shoulder
    u /= np.linalg.norm(u, axis=-1, keepdims=True)
    v = elbow - shoulder
    return v - np.sum(v * u, axis=-1, keepdims=True) * u


def test_the_elbow_stays_on_the_networks_side_over_a_sweep_of_targets() -> None:
    """The head stays where and as the network put it (so the shoulders do not move); each hand
    target sweeps a 9 x 9 x 9 grid of +-8 cm around the network's hand. With the
    elbows the network's alone (``wrist_share=0``), the solved elbow is on the same
    side of the shoulder-target line as the network's, and well away from it (no flip
    through the line)."""
    pos, quat = random_poses(4, seed=4)
    grid = np.linspace(-0.08, 0.08, 9)
    offsets = np.stack(np.meshgrid(grid, grid, grid, indexing="ij"), -1).reshape(-1, 3)
    E = len(offsets) * len(pos)
    pos_e = np.repeat(pos, len(offsets), axis=0)
    quat_e = np.repeat(quat, len(offsets), axis=0)
    shift = np.zeros((E, 4, 3))
    shift[:, 1] = np.tile(offsets, (len(pos), 1))
    shift[:, 2] = -np.tile(offsets, (len(pos), 1))
    tp, tq = trackers(pos_e, shift, random_quats(E, seed=5))
    tq[:, TrackerSlot.HEAD] = quat_e[:, Joint.HEAD]  # the headset as the network's head
    out_pos, out_quat, limited = solve_upper_body(pos_e, quat_e, tp, tq, wrist_share=0.0)
    assert not limited.any()
    for upper, fore, slot in ARMS:
        np.testing.assert_allclose(out_pos[:, upper], pos_e[:, upper], atol=1e-6)
        net = side(pos_e[:, upper], tp[:, slot], pos_e[:, fore])
        got = side(out_pos[:, upper], tp[:, slot], out_pos[:, fore].astype(np.float64))
        cos = np.sum(net * got, -1) / np.linalg.norm(net, axis=-1) / np.linalg.norm(got, axis=-1)
        assert cos.min() > 0.999, cos.min()  # the same plane, the same side
    assert_bones_kept(out_pos)
    assert_fk_consistent(out_pos, out_quat)


def test_out_of_reach_targets_get_a_straight_chain_and_a_flag() -> None:
    """A controller 2 m from its shoulder: the arm points straight at it, bones kept,
    ``reach_limited``; a headset 2 m above the spine: the spine chain straight up."""
    E = 6
    pos, quat = random_poses(E, seed=6)
    shift = np.zeros((E, 4, 3))
    tp, tq = trackers(pos, shift, random_quats(E, seed=7))
    tp[:3, TrackerSlot.LEFT_HAND] = pos[:3, Joint.LEFT_UPPER_ARM] + [2.0, 0.0, 0.0]
    tp[3:, TrackerSlot.HEAD] = pos[3:, Joint.SPINE] + [0.0, 2.0, 0.0]
    out_pos, out_quat, limited = solve_upper_body(pos, quat, tp, tq)
    np.testing.assert_array_equal(limited, True)
    assert_bones_kept(out_pos)
    assert_fk_consistent(out_pos, out_quat)
    p = out_pos.astype(np.float64)
    # The thrown controller: shoulder, elbow and hand on the line toward it.
    u = tp[:3, TrackerSlot.LEFT_HAND] - p[:3, Joint.LEFT_UPPER_ARM]
    u /= np.linalg.norm(u, axis=-1, keepdims=True)
    for joint in (Joint.LEFT_FOREARM, Joint.LEFT_HAND):
        d = p[:3, joint] - p[:3, Joint.LEFT_UPPER_ARM]
        np.testing.assert_allclose(d / np.linalg.norm(d, axis=-1, keepdims=True), u, atol=1e-6)
    reach = BONES[Joint.LEFT_FOREARM] + BONES[Joint.LEFT_HAND]
    np.testing.assert_allclose(
        np.linalg.norm(p[:3, Joint.LEFT_HAND] - p[:3, Joint.LEFT_UPPER_ARM], axis=-1),
        reach,
        atol=1e-6,
    )
    # The other effectors of those poses are still on their trackers.
    np.testing.assert_array_less(
        np.linalg.norm(p[:3, Joint.RIGHT_HAND] - tp[:3, TrackerSlot.RIGHT_HAND], axis=-1), 1e-3
    )
    # The headset far above: the spine chain straight up from the spine joint.
    for joint in (Joint.CHEST, Joint.NECK, Joint.HEAD):
        d = p[3:, joint] - p[3:, Joint.SPINE]
        up = np.tile([0.0, 1.0, 0.0], (3, 1))
        np.testing.assert_allclose(d / np.linalg.norm(d, axis=-1, keepdims=True), up, atol=1e-6)


def test_a_guessed_pelvis_follows_a_headset_beyond_the_spines_reach() -> None:
    """``free_root``: a headset 20 cm beyond the spine chain's reach moves the whole
    body (legs too) by the least that makes it reachable, and the head lands on it; a
    pose whose pelvis is a waist tracker's stays put and is flagged instead."""
    E = 4
    pos, quat = random_poses(E, seed=8)
    tp, tq = trackers(pos, np.zeros((E, 4, 3)), random_quats(E, seed=9))
    v = tp[:, TrackerSlot.HEAD] - pos[:, Joint.SPINE]
    u = v / np.linalg.norm(v, axis=-1, keepdims=True)
    tp[:, TrackerSlot.HEAD] = pos[:, Joint.SPINE] + u * (SPINE_REACH_M + 0.2)
    free = np.array([True, True, False, False])
    out_pos, out_quat, limited = solve_upper_body(pos, quat, tp, tq, free)
    assert_bones_kept(out_pos)
    assert_fk_consistent(out_pos, out_quat)
    p = out_pos.astype(np.float64)
    np.testing.assert_array_less(
        np.linalg.norm(p[:2, Joint.HEAD] - tp[:2, TrackerSlot.HEAD], axis=-1), 1e-3
    )
    np.testing.assert_allclose(p[:2, Joint.PELVIS], pos[:2, Joint.PELVIS] + 0.2 * u[:2], atol=1e-6)
    np.testing.assert_allclose(
        p[:2, Joint.LEFT_TOE], pos[:2, Joint.LEFT_TOE] + 0.2 * u[:2], atol=1e-6
    )
    np.testing.assert_allclose(p[2:, Joint.PELVIS], pos[2:, Joint.PELVIS], atol=1e-6)
    assert limited[2:].all()
    # Within reach nothing moves.
    near = reach_shift(pos, pos[:, Joint.SPINE] + 0.4 * u)
    np.testing.assert_array_equal(near, 0.0)


def test_a_guessed_pelvis_follows_a_controller_beyond_the_arms_reach() -> None:
    """``reach_root``: a controller 30 cm beyond its arm's reach, out to the side (the
    headset and the other controller 30 cm that way with it), moves the body toward it
    horizontally by about that much (the softplus adds up to 2 * ln 2 * its width),
    after which the arm nearly reaches it; a controller 30 cm beyond reach straight
    below the shoulder moves nothing vertically (the arm reaches down as far as it
    can); controllers within reach move the body by under a centimetre (the softplus
    starts before the arm is straight). The headset
    wins: with it left where it was, the body moves only as far as the spine still
    reaches it."""
    E = 4
    pos, quat = random_poses(E, seed=12)
    tp, tq = trackers(pos, np.zeros((E, 4, 3)), quat)
    # Headsets within the spine's reach: 40 % nearer the spine than the head (so 30 cm
    # to the side they still are), and for the last pose 2 % (so they are not).
    near = np.array([0.6, 0.6, 0.6, 0.98])[:, None]
    tp[:, TrackerSlot.HEAD] = pos[:, Joint.SPINE] + near * (
        pos[:, Joint.HEAD] - pos[:, Joint.SPINE]
    )
    out = np.array([1.0, 0.0, 0.0])
    for e in (0, 3):  # the right controller moves with the body
        tp[e, TrackerSlot.LEFT_HAND] = pos[e, Joint.LEFT_UPPER_ARM] + out * (ARM_REACH_M + 0.3)
        tp[e, TrackerSlot.RIGHT_HAND] += out * 0.3
    tp[0, TrackerSlot.HEAD] += out * 0.3
    tp[1, TrackerSlot.LEFT_HAND] = pos[1, Joint.LEFT_UPPER_ARM] - [0.0, ARM_REACH_M + 0.3, 0.0]
    shift = reach_root(pos, tp, span=0.0)  # the torso's span: the test after this one
    assert shift.shape == (E, 3) and shift.dtype == np.float64
    head_start = 2.0 * np.log(2.0) * HAND_REACH_SOFTNESS_M
    assert 0.3 <= shift[0, 0] <= 0.3 + head_start and np.abs(shift[0, 1:]).max() < 1e-3
    np.testing.assert_array_less(np.abs(shift[1:3]), 0.01)  # the softplus's start only
    np.testing.assert_array_equal(shift[1:3, 1], 0.0)  # never vertically
    spine_to_head = tp[3, TrackerSlot.HEAD] - (pos[3, Joint.SPINE] + shift[3])
    assert shift[3, 0] > 0.1
    assert np.linalg.norm(spine_to_head) <= SPINE_REACH_M + 1e-9
    # The pass on the moved body leaves the controller under a third as far out of
    # reach as on the body where the network put it (not nearer: the chain's lean and
    # bend toward a headset 40 % nearer the spine carry the shoulder).
    free = np.ones(E, np.bool_)
    miss = []
    for body in (pos, pos + shift[:, None]):
        out_pos, _, limited = solve_upper_body(body, quat, tp, tq, free)
        hand = out_pos[:, Joint.LEFT_HAND] - tp[:, TrackerSlot.LEFT_HAND]
        miss.append(np.linalg.norm(hand, axis=-1))
        assert limited[1] and limited[3]
    assert miss[0][0] > 0.2 and miss[1][0] < 0.33 * miss[0][0]
    # Only the spine, the shoulders and the head are read: the others may be anything.
    partial = np.full_like(pos, np.nan)
    keep = list(REACH_JOINTS)
    partial[:, keep] = pos[:, keep]
    np.testing.assert_array_equal(reach_root(partial, tp, span=0.0), shift)
    np.testing.assert_array_equal(reach_root(partial, tp), reach_root(pos, tp))


def test_a_guessed_body_keeps_the_networks_torso_span_to_the_headset() -> None:
    """``reach_root``'s last move: a headset 10 cm nearer the spine than the network's
    head (pose 0), 5 cm further (pose 1, within the spine's reach), or 10 cm down
    (pose 2; controllers where the hands are, so the hand reach moves little): the body
    moves along the line from its spine to the headset until the spine is exactly as
    far from the headset as the network's head was (``span=0.5``: half the gap;
    ``span=0``: no move along it); the upper-body pass then turns the chest less away
    from the network's than on the body left where it was (the chain folds the rest)."""
    E = 3
    pos, quat = random_poses(E, seed=5)
    tp, tq = trackers(pos, np.zeros((E, 4, 3)), quat)
    spine, head = pos[:, Joint.SPINE], pos[:, Joint.HEAD]
    torso = np.linalg.norm(head - spine, axis=-1)
    line = (head - spine) / torso[:, None]
    tp[0, TrackerSlot.HEAD] -= 0.1 * line[0]
    tp[1, TrackerSlot.HEAD] += 0.05 * line[1]
    tp[2, TrackerSlot.HEAD, 1] -= 0.1
    shift = reach_root(pos, tp)
    kept = np.linalg.norm(tp[:, TrackerSlot.HEAD] - (spine + shift), axis=-1)
    np.testing.assert_allclose(kept, torso, atol=1e-9)
    none = reach_root(pos, tp, span=0.0)
    np.testing.assert_array_less(np.abs(none[[0, 2]]), 0.03)  # the softplus's start
    half = np.linalg.norm(
        tp[:, TrackerSlot.HEAD] - (spine + reach_root(pos, tp, span=0.5)), axis=-1
    )
    before = np.linalg.norm(tp[:, TrackerSlot.HEAD] - (spine + none), axis=-1)
    np.testing.assert_allclose(half, 0.5 * (before + torso), atol=1e-9)
    assert shift[0] @ line[0] < -0.09 and shift[1] @ line[1] > 0.04 and shift[2, 1] < -0.05
    free = np.ones(E, np.bool_)
    turned = []
    for body in (pos + none[:, None], pos + shift[:, None]):
        _, rot, _ = solve_upper_body(body, quat, tp, tq, free)
        chest = quat2mat(rot[:, Joint.CHEST].astype(np.float64))
        net = quat2mat(quat[:, Joint.CHEST].astype(np.float64))
        cos = (np.trace(np.swapaxes(chest, -1, -2) @ net, axis1=-2, axis2=-1) - 1.0) / 2.0
        turned.append(np.degrees(np.arccos(np.clip(cos, -1.0, 1.0))))
    assert turned[1][0] < turned[0][0] - 1.0 and turned[1][2] < turned[0][2] - 1.0


def test_the_shown_move_eases_toward_reach_roots() -> None:
    """``ease_reach``: a first frame takes the move whole; a step of the target is
    followed by ``REACH_EASE`` of what is left each frame (no overshoot); the engine
    and the evaluation share it (``ease_reach_clip``)."""
    target = np.zeros((8, 3))
    target[2:, 0] = 0.1
    shown = ease_reach_clip(target)
    np.testing.assert_array_equal(shown[:2], 0.0)
    left = 0.1 * (1.0 - REACH_EASE) ** np.arange(1, 7)
    np.testing.assert_allclose(0.1 - shown[2:, 0], left, atol=1e-12)
    np.testing.assert_array_equal(ease_reach(None, target[5]), target[5])
    assert 0.0 < REACH_EASE < 1.0


def test_a_guessed_pelvis_leans_so_the_line_to_the_head_meets_the_headset() -> None:
    """``lean_root`` and ``turn_pelvis``: the turned pelvis carries the upper body
    about itself (the pelvis stays, the bones keep their lengths) so the line from it
    to the head points at the headset, by the smallest turn (a swing); the thighs keep
    their world rotations, so each leg only follows its hip."""
    E = 6
    rng = np.random.default_rng(21)
    rot6d = mat2r6d(aa2mat(rng.normal(0.0, 0.3, (E, 18, 3)))).reshape(E, 108).astype(np.float32)
    root_mat = aa2mat(rng.normal(0.0, 0.1, (E, 3)))
    root_pos = np.array([0.0, 0.95, 0.0]) + rng.normal(0.0, 0.03, (E, 3))
    wm, wp = pose_from_rotations(rot6d.reshape(E, 18, 6), root_mat, root_pos)
    pelvis, head = wp[:, Joint.PELVIS], wp[:, Joint.HEAD]
    # The headset 15 cm forward and 12 cm lower than the network's head: bent over.
    headset = head + np.array([0.0, -0.12, 0.15])
    turn = lean_root(pelvis, head, headset)
    new_rot, new_root = turn_pelvis(rot6d, root_mat, turn)
    assert new_rot.shape == rot6d.shape and new_rot.dtype == rot6d.dtype
    nm, npos = pose_from_rotations(new_rot.reshape(E, 18, 6), new_root, root_pos)
    line = npos[:, Joint.HEAD] - npos[:, Joint.PELVIS]
    want = headset - pelvis
    cos = np.sum(line * want, -1) / np.linalg.norm(line, axis=-1) / np.linalg.norm(want, axis=-1)
    assert cos.min() > 1 - 1e-6
    np.testing.assert_allclose(npos[:, Joint.PELVIS], pelvis, atol=1e-9)
    np.testing.assert_allclose(
        np.linalg.norm(line, axis=-1), np.linalg.norm(head - pelvis, axis=-1)
    )
    for thigh in (Joint.LEFT_THIGH, Joint.RIGHT_THIGH):
        np.testing.assert_allclose(nm[:, thigh], wm[:, thigh], atol=1e-5)
    upper = [j for j in range(1, 19) if j not in LOWER_BODY]
    np.testing.assert_allclose(nm[:, upper], turn[:, None] @ wm[:, upper], atol=1e-5)
    axis = mat2aa(turn)  # a swing: about the axis square to both lines, no twist about them
    axis /= np.linalg.norm(axis, axis=-1, keepdims=True)
    np.testing.assert_allclose(np.sum(axis * (head - pelvis), -1), 0.0, atol=1e-9)
    np.testing.assert_allclose(np.sum(axis * want, -1), 0.0, atol=1e-9)


@pytest.mark.parametrize("deg", [10.0, 29.0, 45.0, 90.0, 150.0])
def test_a_guessed_pelvis_leans_at_most_lean_most_rad(deg: float) -> None:
    """A headset ``deg`` degrees off the line from the pelvis to the network's head (about
    a horizontal axis): the pelvis turns by that angle up to ``LEAN_MOST_RAD`` (30
    degrees), and no further, about the same axis; the spine chain takes the rest."""
    pelvis = np.array([[0.0, 0.95, 0.0]])
    head = pelvis + np.array([[0.0, 0.6, 0.0]])
    t = np.radians(deg)
    headset = pelvis + 0.5 * np.array([[0.0, np.cos(t), np.sin(t)]])  # leant forward
    turn = lean_root(pelvis, head, headset)
    angle = np.degrees(np.linalg.norm(mat2aa(turn), axis=-1))
    np.testing.assert_allclose(angle, min(deg, np.degrees(LEAN_MOST_RAD)), atol=1e-9)
    line = (turn[0] @ (head - pelvis)[0])[None]
    bent = np.degrees(np.arctan2(line[0, 2], line[0, 1]))  # forward from upright
    assert bent == pytest.approx(min(deg, 30.0), abs=1e-9)
