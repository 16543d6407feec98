"""The upper-body pass: head on the headset, hands on the controllers (numpy, batched).

The network places the head and hands *near* their trackers; a VR user expects them *on*
them. This pass runs on the shown poses of a tick (``E`` players, after SSI and the
display foot IK, in calibrated canonical-body metres) and changes rotations only:
every bone keeps its length, and every joint's world rotation stays what FK of the
local rotations gives (a joint that turns carries its whole subtree with it).

1. **Spine chain** (``SPINE -> CHEST -> NECK -> HEAD``): the spine, then the chest,
   turns by :data:`LEAN_SHARE` of the swing that aims the line from it to the head at
   the headset (a player who bends over leans the chain; the network's own bends
   kept). The neck then turns by :data:`NECK_SHARE` of the turn the network's head
   still needs to take the headset's rotation, and a two-bone solve of spine and chest
   puts the neck joint where that neck holds the head on the headset (twice). An exact finish: one
   FABRIK sweep spreads what is left over the three bones, then two two-bone solves
   (spine-chest against the rest of the chain, then chest-neck-head) put the head on
   the headset; each bone turns by the smallest rotation (a swing) that points it at
   its new child, carrying the arms along. The head's world rotation becomes the
   headset's.
2. **Arms**, from the shoulders where the chest now holds them: a two-bone solve
   (upper arm, forearm) puts the hand on the controller, the elbow in the plane of
   shoulder, target and a hint, on the hint's side of the shoulder-target line (so
   the elbow never flips). The hint is the network's own elbow blended, by
   ``wrist_share`` (:data:`WRIST_ELBOW_SHARE`), with the elbow a straight wrist
   would put behind the controller (the controller's rotation gives the forearm's
   direction): a controller held palm down or turned up says where the elbow is. The
   hand's world rotation becomes the controller's.
3. **Out of reach** (bad calibration, a thrown controller): the chain reaches straight
   along the line to the target, as far as its bones allow, and the pose is flagged:
   ``reach_limited`` is true when any of the three effectors ends more than
   :data:`REACH_TOLERANCE_M` from its tracker. The engine (``hand_reach``) moves a
   pelvis that is the network's guess (no waist tracker) toward what it cannot reach
   before the leg passes plant the feet (:func:`reach_root`, :func:`ease_reach`); this
   function does not.

Glossary as in :mod:`posecast.geometry.rotations` (``mat`` acts on column vectors,
``quat`` is xyzw). Pure numpy: no inference library, no I/O.
"""

from __future__ import annotations

import itertools
from collections.abc import Callable

import numpy as np
from numpy.typing import NDArray

from posecast.body.geom import BONE_M, EPS, cross3, norm3, swing_mat, turn_joint, unit3
from posecast.geometry.rotations import (
    axis_angle_mat,
    mat2quat,
    mat2r6d,
    quat2mat,
    r6d2mat,
)
from posecast.skeleton import Joint, reference_offsets
from posecast.tracking.features import TRACKER_JOINT_INDEX, TrackerSlot

F32 = NDArray[np.float32]
F64 = NDArray[np.float64]

REACH_TOLERANCE_M = 1e-3  # an effector further than this from its tracker is "not reached"
FABRIK_SWEEPS = 1  # shaping only: two exact solves finish (solve_upper_body)

_SPINE_CHAIN = (Joint.SPINE, Joint.CHEST, Joint.NECK, Joint.HEAD)
# Both arms at once, left then right: upper arm, forearm, hand, and the hand's tracker.
_ARM_UPPER = [int(Joint.LEFT_UPPER_ARM), int(Joint.RIGHT_UPPER_ARM)]
_ARM_FORE = [int(Joint.LEFT_FOREARM), int(Joint.RIGHT_FOREARM)]
_ARM_HAND = [int(Joint.LEFT_HAND), int(Joint.RIGHT_HAND)]
_HAND_SLOTS = [int(TrackerSlot.LEFT_HAND), int(TrackerSlot.RIGHT_HAND)]
# Joints whose rotation the pass may change (the rest are copied through untouched).
_UPPER = list(range(Joint.SPINE, Joint.LEFT_THIGH))  # spine, neck, head and the arms


def _point_bone(pos: F64, mat: F64, joint: int, child: int, new_child: F64) -> None:
    """Swing ``joint`` so that its bone to ``child`` points at ``new_child (E, 3)``."""
    R = swing_mat(pos[:, child] - pos[:, joint], new_child - pos[:, joint])
    turn_joint(pos, mat, joint, R)


def fabrik(chain: F64, lengths: F64, target: F64, iterations: int = 1) -> F64:
    """``iterations`` sweeps of FABRIK (Aristidou & Lasenby 2011) on ``E`` chains
    ``(E, n, 3)`` with fixed roots and bone ``lengths (n - 1,)``: the new joint
    positions (each sweep: from the target back to the root, then forward again)."""
    p = chain.copy()
    root = p[:, 0].copy()
    n = p.shape[1]
    for _ in range(iterations):
        p[:, -1] = target
        for i in range(n - 2, -1, -1):  # backward: from the target to the root
            u, _ = unit3(p[:, i] - p[:, i + 1])
            p[:, i] = p[:, i + 1] + lengths[i] * u
        p[:, 0] = root
        for i in range(n - 1):  # forward: from the root to the end
            u, _ = unit3(p[:, i + 1] - p[:, i])
            p[:, i + 1] = p[:, i] + lengths[i] * u
    return p


def two_bone(
    shoulder: F64, elbow: F64, target: F64, l1: float, l2: F64 | float, bend: F64
) -> tuple[F64, F64]:
    """Elbow and hand positions ``(E, 3)`` of a two-bone limb (lengths ``l1``, ``l2``,
    the second may differ per row) from ``shoulder`` to a hand on ``target``, the elbow
    in the plane of shoulder, target and the current ``elbow``, on its side of the
    shoulder-target line; a straight limb gives no plane and bends toward ``bend (E, 3)``.
    Out of reach: straight at the target."""
    u, d = unit3(target - shoulder)
    w, wn = unit3(_across(elbow - shoulder, u))
    for fallback in (bend, [[1.0, 0.0, 0.0]], [[0.0, 1.0, 0.0]]):
        bad = wn < 1e-6
        if not bad.any():
            break
        alt, altn = unit3(_across(np.broadcast_to(np.asarray(fallback, np.float64), u.shape), u))
        w, wn = np.where(bad[:, None], alt, w), np.where(bad, altn, wn)
    l2 = np.asarray(l2, np.float64)
    dc = np.clip(d, np.abs(l1 - l2) + EPS, l1 + l2)
    cos_a = np.clip((l1 * l1 + dc * dc - l2 * l2) / (2.0 * l1 * dc), -1.0, 1.0)
    sin_a = np.sqrt(1.0 - cos_a * cos_a)
    new_elbow = shoulder + l1 * (cos_a[:, None] * u + sin_a[:, None] * w)
    return new_elbow, shoulder + dc[:, None] * u


def _across(v: F64, u: F64) -> F64:
    """The part of ``v`` perpendicular to the unit ``u`` (both ``(E, 3)``)."""
    out: F64 = v - np.einsum("ei,ei->e", v, u)[:, None] * u
    return out


def reach_shift(positions: F64, head_target: F64) -> F64:
    """Per pose ``(E, 3)``, the smallest move of the whole body that brings the spine
    joint within :data:`SPINE_REACH_M` of the headset ``(E, 3)`` (zero where it is)."""
    return _spine_shift(positions[:, Joint.SPINE], head_target)


def _spine_shift(spine: F64, head_target: F64) -> F64:
    return _along(spine, head_target, lambda d: np.maximum(d - SPINE_REACH_M, 0.0))


def _along(origin: F64, target: F64, gap: Callable[[F64], F64]) -> F64:
    """The move ``(E, 3)`` of ``origin`` along the line to ``target`` (both ``(E, 3)``)
    by ``gap(d)`` metres, ``d (E,)`` their distance (a negative gap: away)."""
    v = target - origin
    d = norm3(v)
    out: F64 = v * (gap(d) / np.maximum(d, EPS))[:, None]
    return out


# How far the spine chain (spine -> chest -> neck -> head, 0.52 m) may reach before a
# pose whose pelvis is a guess (no waist tracker) is moved instead: nearly straight.
SPINE_REACH_M = float(BONE_M[[Joint.CHEST, Joint.NECK, Joint.HEAD]].sum()) - 0.01

# How far an arm (shoulder -> elbow -> hand) reaches, nearly straight, and how softly a
# guessed pelvis starts to follow a controller beyond it: the move is the softplus of
# the overreach at this width (metres), so it sets in smoothly instead of with a kink
# the jitter shows. Chosen on the validation split (docs/evaluation.md, "Hands out of
# reach: a guessed pelvis follows the controllers").
ARM_REACH_M = float(BONE_M[_ARM_FORE[0]] + BONE_M[_ARM_HAND[0]]) - 0.01
HAND_REACH_SOFTNESS_M = 0.05
_REACH_ROUNDS = 2  # the move toward the controllers, again from where the first put it


# The share of the gap between where a body whose pelvis is a guess holds its spine
# and where the network's own torso would (the spine's distance from the headset
# against the network's spine-to-head distance) that the body moves along the line
# from its spine to the headset (reach_root), rather than leave the spine chain to
# fold or stretch that gap away: a nearly straight chain shortened by a centimetre
# bends by tens of degrees (headset-only chest rotations 34 degrees off the truth on
# the validation split, against 13 for the network's own). A body so moved keeps the
# network's torso, its spine's bends, and the headset decides where the guessed pelvis
# stands. The feet it sinks are lifted by the floor pass, knees bent: a crouch. Not for
# a tracker set that senses its legs, whose leg pass turns the legs as its trackers say
# after the floor pass (it would sink the feet again: 0.7 % of frames with feet under
# the floor on val with two foot IMUs), as it keeps such a set's hips from leaning.
# Chosen on the validation split among 0.5, 0.75 and 1 (docs/evaluation.md, "A guessed
# body keeps the network's torso"); it replaced lowering the body by half the height
# its network head stood above the headset.
SPAN_SHARE = 1.0


def reach_root(
    positions: NDArray[np.floating],
    tracker_pos: NDArray[np.floating],
    span: float | NDArray[np.floating] | None = None,
) -> F64:
    """Per pose ``(E, 3)``, the move of a whole body whose pelvis is a guess that brings
    the headset within the spine's reach (:func:`reach_shift`), brings each controller,
    horizontally, within its arm's reach (the controllers of a player who reaches for
    something: a person steps or leans toward it, and the network, which does not know
    how far the arms are, left the body behind), and last moves the body along the
    line from its spine to the headset by ``span`` (default :data:`SPAN_SHARE`; one
    share, or one per pose ``(E,)``) of the difference between the spine's distance
    from the headset and the network's own spine-to-head distance, so that the spine
    chain reaches the headset with the network's torso instead of folding it.
    Vertical overreach of the controllers stays with the arms (a person crouches
    rather than sinks), and the headset wins: the body moves toward a controller only
    as far as the spine still reaches the headset from there.

    Reads only the spine, shoulder and head rows of ``positions (E, 19, 3)`` (FK of
    the network's pose: :data:`REACH_JOINTS`); ``tracker_pos (E, >=3, 3)`` in slot
    order.
    """
    spine = np.asarray(positions[:, Joint.SPINE], np.float64)  # (E, 3)
    shoulders = np.asarray(positions[:, _ARM_UPPER], np.float64)  # (E, 2, 3)
    tp = np.asarray(tracker_pos, np.float64)
    head = tp[:, TrackerSlot.HEAD]
    shift = _spine_shift(spine, head)
    w = HAND_REACH_SOFTNESS_M
    for _ in range(_REACH_ROUNDS):
        v = tp[:, _HAND_SLOTS] - (shoulders + shift[:, None])  # (E, 2, 3)
        d = norm3(v)
        over = w * np.logaddexp(0.0, (d - ARM_REACH_M) / w)  # softplus of the overreach
        step = (v * (over / np.maximum(d, EPS))[..., None]).sum(axis=1)
        step[:, 1] = 0.0  # its horizontal part
        shift = shift + _within(head - (spine + shift), step, SPINE_REACH_M)[:, None] * step
    share = np.asarray(SPAN_SHARE if span is None else span, np.float64)
    if np.any(share > 0.0):
        torso = norm3(np.asarray(positions[:, Joint.HEAD], np.float64) - spine)
        shift = shift + _along(spine + shift, head, lambda d: share * (d - torso))
    return shift


def _within(c: F64, step: F64, radius: float) -> F64:
    """Per row, the largest ``t`` in ``[0, 1]`` with ``|c - t * step| <= radius``, for
    ``|c| <= radius`` (``(E, 3)`` each): how much of a move the headset allows."""
    a = np.einsum("ei,ei->e", step, step)
    b = np.einsum("ei,ei->e", c, step)
    slack = np.maximum(radius * radius - np.einsum("ei,ei->e", c, c), 0.0)
    t = (b + np.sqrt(b * b + a * slack)) / np.maximum(a, EPS * EPS)
    out: F64 = np.clip(t, 0.0, 1.0)
    return out


REACH_JOINTS = (int(Joint.SPINE), *_ARM_UPPER, int(Joint.HEAD))  # what reach_root reads
LEAN_JOINTS = REACH_JOINTS  # lean_root reads the head too
_THIGHS = [int(Joint.LEFT_THIGH) - 1, int(Joint.RIGHT_THIGH) - 1]  # their network rows


# The most a guessed pelvis leans (lean_root), radians. The full swing bent the hips
# past human range on samples whose network head was far from the headset (SSI's
# destinations on the validation split's dances: joint-angle flags 0.36 % of the
# streamed headset-only frames against 0.05 % without SSI); 30 degrees, chosen on the
# validation split among 10, 20, 30 and 45 degrees, hard and soft (tanh) caps
# (docs/evaluation.md, "How far a guessed pelvis leans").
LEAN_MOST_RAD = np.radians(30.0)


def lean_root(pelvis: NDArray[np.floating], head: NDArray[np.floating], head_target: F64) -> F64:
    """Per pose, the turn ``(E, 3, 3)`` of a guessed pelvis about itself that aims the
    line from it to the network's head ``(E, 3)`` at the headset ``(E, 3)``: the
    smallest rotation (a swing; about a horizontal axis when both lines are upright,
    so the heading stays), by at most :data:`LEAN_MOST_RAD` (the rest is the spine
    chain's). A player who bends over leans from the hips; the network, which leans
    too little then, left the spine to fold toward the headset."""
    p = np.asarray(pelvis, np.float64)
    a, b = np.asarray(head, np.float64) - p, np.asarray(head_target, np.float64) - p
    return _part_of_swing(a, b, 1.0, LEAN_MOST_RAD)


def turn_pelvis(
    rot6d: NDArray[np.floating], root_mat: NDArray[np.floating], turn: F64
) -> tuple[NDArray[np.floating], NDArray[np.floating]]:
    """The network's pose ``rot6d (E, 108)`` or ``(E, 18, 6)`` on a pelvis
    ``root_mat (E, 3, 3)`` turned by ``turn (E, 3, 3)`` on the left: the upper body
    turns with the pelvis, the thighs keep their world rotations (their local ones
    take the turn back), so the legs only follow the hips. Returns the new
    ``(rot6d, root_mat)``, in the inputs' shapes and dtypes."""
    old = np.asarray(root_mat, np.float64)
    new = np.asarray(turn, np.float64) @ old
    rows = np.array(rot6d, copy=True).reshape(len(old), -1, 6)
    back = np.swapaxes(new, -1, -2) @ old  # (E, 3, 3): new^T old
    thighs = back[:, None] @ r6d2mat(rows[:, _THIGHS].astype(np.float64))
    rows[:, _THIGHS] = mat2r6d(thighs)
    return rows.reshape(np.shape(rot6d)), new.astype(np.asarray(root_mat).dtype)


# The shown move follows reach_root's by this share a frame (an exponential average, a
# time constant of about 3 frames at 60 Hz): the move answers the hands' motion frame
# by frame, which the shown body would otherwise shake with. Chosen on the validation
# split (docs/evaluation.md, "Hands out of reach").
REACH_EASE = 0.3


def ease_reach(previous: F64 | None, target: F64) -> F64:
    """One frame of the shown move ``(..., 3)`` toward ``target`` (``previous`` None:
    a first frame, which takes the target as it is)."""
    if previous is None:
        return target
    out: F64 = previous + REACH_EASE * (target - previous)
    return out


def ease_reach_clip(targets: F64) -> F64:
    """:func:`ease_reach` along a clip's frames ``(T, 3)`` (the engine's, offline)."""
    out = np.empty_like(targets)
    previous: F64 | None = None
    for t, target in enumerate(targets):
        previous = out[t] = ease_reach(previous, target)
    return out


def _neck(chest_mat: F64, neck_local: F64, head_local: F64, head_mat: F64) -> F64:
    """The neck's world rotations ``(E, 3, 3)`` under a chest ``chest_mat``: the
    network's (``neck_local``, relative to the chest) turned by :data:`NECK_SHARE` of
    the turn that the head, at its own ``head_local``, still needs to take the
    headset's ``head_mat``. Nothing turns when the network's head has it already."""
    held = chest_mat @ neck_local
    rest = np.swapaxes(held, -1, -2) @ head_mat @ np.swapaxes(head_local, -1, -2)
    out: F64 = held @ _part_of_turn(rest, NECK_SHARE)
    return out


def _part_of_swing(a: F64, b: F64, share: float, most_rad: float = np.pi) -> F64:
    """``share`` of the smallest rotation ``(E, 3, 3)`` taking direction ``a (E, 3)``
    onto ``b``: about the same axis, by that share of the angle, at most ``most_rad``
    (none for directions exactly opposite, which have no smallest rotation)."""
    ua, _ = unit3(a)
    ub, _ = unit3(b)
    v = cross3(ua, ub)
    s = norm3(v)
    c = np.einsum("ei,ei->e", ua, ub)
    angle = np.where(s > EPS, share * np.arctan2(s, c), 0.0)  # opposite: no turn
    return axis_angle_mat(v / np.maximum(s, EPS)[:, None], np.minimum(angle, most_rad))


def _part_of_turn(R: F64, share: float) -> F64:
    """``share`` of each rotation ``R (E, 3, 3)``: about its axis, by that share of its
    angle (at most half a turn)."""
    q = mat2quat(R)
    q = np.where(q[:, 3:] < 0.0, -q, q)
    s = norm3(q[:, :3])
    return axis_angle_mat(
        q[:, :3] / np.maximum(s, EPS)[:, None], share * 2.0 * np.arctan2(s, q[:, 3])
    )


# The spine chain's lean: the share of the swing aiming the line from the spine (then
# from the chest) to the head at the headset that each of the two takes before the
# rest is solved. The network, which leans too little when a player bends over (the
# headset 10 cm or more under its head on a tenth of the validation frames for the
# headset-only model), left all of it to the exact solve, which folded the neck.
# Chosen on the validation split (docs/evaluation.md, "The spine chain: lean, then
# the neck's share").
LEAN_SHARE = 0.8
# The share the neck takes of the turn (swing and twist) that the network's head still
# needs to take the headset's rotation, the head keeping the rest, as the neck sits
# between chest and head. Chosen on the validation split with LEAN_SHARE (the same
# section).
NECK_SHARE = 0.5
_NECK_ROUNDS = 2  # neck placed, spine and chest solved, neck turned again
_HEAD_OFFSET = reference_offsets()[Joint.HEAD]  # (3,) the head from the neck, neck frame

# The share of the elbow hint that comes from the controller's rotation (a straight
# wrist: the forearm along the hand's rest direction, rotated by the controller), the
# rest from the network's own elbow. Chosen on the validation split (docs/evaluation.md,
# "Elbows: the controller's rotation"): 1.0 was closest in position there, 0.75 in
# rotation and within 0.05 cm. The mocap wrists there hardly bend (0 degrees at the
# median, 14 at the 90th percentile: `posecast data wrists`), a player's do, so the
# network keeps a quarter.
WRIST_ELBOW_SHARE = 0.75
_HAND_DIR = reference_offsets()[_ARM_HAND] / BONE_M[_ARM_HAND][:, None]  # (2, 3) at rest


def straight_forearms(hand_mat: NDArray[np.floating]) -> F64:
    """Unit forearm directions ``(..., 2, 3)`` (left, right; elbow to hand) that a
    straight wrist gives hands of world rotations ``hand_mat (..., 2, 3, 3)``: the
    hand's rest bone direction turned by its rotation."""
    out: F64 = np.einsum("...kab,kb->...ka", np.asarray(hand_mat, np.float64), _HAND_DIR)
    return out


def solve_upper_body(
    positions: NDArray[np.floating],
    rotations: NDArray[np.floating],
    tracker_pos: NDArray[np.floating],
    tracker_quat: NDArray[np.floating],
    free_root: NDArray[np.bool_] | None = None,
    wrist_share: float = WRIST_ELBOW_SHARE,
) -> tuple[F32, F32, NDArray[np.bool_]]:
    """Head and hands of ``E`` poses onto their trackers.

    Args:
        positions: world joint positions ``(E, 19, 3)`` (FK of ``rotations``), metres.
        rotations: world joint rotations ``(E, 19, 4)`` xyzw.
        tracker_pos: the trackers ``(E, 4, 3)`` in the same frame and scale, slot order.
        tracker_quat: their orientations ``(E, 4, 4)`` xyzw (calibration offsets applied).
        free_root: per pose, whether its pelvis is the network's guess (no waist
            tracker): a headset beyond the spine's reach then moves the whole body
            toward it (:func:`reach_shift`) instead of leaving the head short.
        wrist_share: how much of each elbow's hint comes from its controller's
            rotation, the rest from the network's elbow (0: the network's alone).

    Returns:
        ``(positions (E, 19, 3), rotations (E, 19, 4), reach_limited (E,))``: float32
        poses whose world rotations are still FK-consistent with the positions, and
        per pose whether an effector was left more than :data:`REACH_TOLERANCE_M` away.
    """
    pos = np.asarray(positions, np.float64).copy()  # (E, 19, 3)
    quat_in = np.asarray(rotations)
    mat = quat2mat(quat_in)  # (E, 19, 3, 3)
    tp = np.asarray(tracker_pos, np.float64)
    tq = np.asarray(tracker_quat, np.float64)
    if free_root is not None and free_root.any():
        rows = np.flatnonzero(free_root)
        pos[rows] += reach_shift(pos[rows], tp[rows, TrackerSlot.HEAD])[:, None]

    # 1. The spine chain. First the lean: the spine, then the chest, turns by
    # LEAN_SHARE of the swing that aims the line from it to the head at the headset
    # (the network's bends kept, the chain leant from its base). Then the neck takes
    # NECK_SHARE of the turn the network's head still needs, and spine and chest (a
    # two-bone solve) put the neck joint where that neck holds the head on the headset.
    # Last the exact finish: a FABRIK sweep spreads what is left over the three bones
    # (more sweeps converge slowly near full extension, where a standing user's headset
    # is, and cost a tick's time), then two two-bone solves from its shape: the chest at
    # its distance from the target (within what neck and head can span), then neck and
    # head onto the target.
    chain = [int(j) for j in _SPINE_CHAIN]
    spine, chest_j, neck_j, head_j = chain
    head_target = tp[:, TrackerSlot.HEAD]
    tracker_mat = quat2mat(tq)  # (E, 4, 3, 3)
    head_mat = tracker_mat[:, TrackerSlot.HEAD]
    neck_local = np.swapaxes(mat[:, chest_j], -1, -2) @ mat[:, neck_j]  # the network's
    head_local = np.swapaxes(mat[:, neck_j], -1, -2) @ mat[:, head_j]
    for joint in (spine, chest_j):
        aim = pos[:, head_j] - pos[:, joint], head_target - pos[:, joint]
        turn_joint(pos, mat, joint, _part_of_swing(*aim, LEAN_SHARE))
    lengths = BONE_M[chain[1:]]  # spine-chest, chest-neck, neck-head
    forward = mat[:, Joint.CHEST, :, 2]  # the chest's +Z: where a straight spine bends
    for _ in range(_NECK_ROUNDS):
        neck_mat = _neck(mat[:, chest_j], neck_local, head_local, head_mat)
        neck_at = head_target - neck_mat @ _HEAD_OFFSET
        chest, _ = two_bone(
            pos[:, spine], pos[:, chest_j], neck_at, lengths[0], lengths[1], forward
        )
        _point_bone(pos, mat, spine, chest_j, chest)
        _point_bone(pos, mat, chest_j, neck_j, neck_at)
        neck_mat = _neck(mat[:, chest_j], neck_local, head_local, head_mat)
        turn_joint(pos, mat, neck_j, neck_mat @ np.swapaxes(mat[:, neck_j], -1, -2))
    shaped = fabrik(pos[:, chain], lengths, head_target, FABRIK_SWEEPS)  # (E, 4, 3)
    span = np.clip(
        norm3(head_target - shaped[:, 1]),
        abs(lengths[1] - lengths[2]),
        lengths[1] + lengths[2],
    )
    chest, _ = two_bone(pos[:, spine], shaped[:, 1], head_target, lengths[0], span, forward)
    neck, head = two_bone(chest, shaped[:, 2], head_target, lengths[1], lengths[2], forward)
    for (joint, child), placed in zip(itertools.pairwise(chain), (chest, neck, head), strict=True):
        _point_bone(pos, mat, joint, child, placed)
    mat[:, Joint.HEAD] = head_mat

    # 2. Both arms in one batch, from where the chest now holds the shoulders.
    upper, fore, hand = _ARM_UPPER, _ARM_FORE, _ARM_HAND
    shoulder = pos[:, upper]  # (E, 2, 3)
    hand_target = tp[:, _HAND_SLOTS]  # (E, 2, 3)
    hint = pos[:, fore]
    if wrist_share > 0.0:
        # A straight wrist: the forearm points where the controller's rest direction does.
        behind = hand_target - float(BONE_M[hand[0]]) * straight_forearms(
            tracker_mat[:, _HAND_SLOTS]
        )
        hint = (1.0 - wrist_share) * hint + wrist_share * behind
    elbow, wrist = two_bone(
        shoulder.reshape(-1, 3),
        hint.reshape(-1, 3),
        hand_target.reshape(-1, 3),
        float(BONE_M[fore[0]]),
        float(BONE_M[hand[0]]),
        np.array([[0.0, -1.0, 0.0]]),  # where a straight network arm bends its elbow
    )
    elbow, wrist = elbow.reshape(-1, 2, 3), wrist.reshape(-1, 2, 3)
    # The upper arms turn, carrying forearm and hand; then the forearms.
    R = swing_mat(pos[:, fore] - shoulder, elbow - shoulder)  # (E, 2, 3, 3)
    for j in (fore, hand):
        pos[:, j] = shoulder + np.einsum("ekab,ekb->eka", R, pos[:, j] - shoulder)
    for j in (upper, fore):
        mat[:, j] = R @ mat[:, j]
    R = swing_mat(pos[:, hand] - pos[:, fore], wrist - pos[:, fore])
    pos[:, hand] = pos[:, fore] + np.einsum("ekab,ekb->eka", R, pos[:, hand] - pos[:, fore])
    mat[:, fore] = R @ mat[:, fore]
    mat[:, hand] = tracker_mat[:, _HAND_SLOTS]

    # 3. What was not reached.
    slots = [int(TrackerSlot.HEAD), *_HAND_SLOTS]
    effectors = [TRACKER_JOINT_INDEX[slot] for slot in slots]
    miss = norm3(pos[:, effectors] - tp[:, slots])  # (E, 3)
    reach_limited = np.any(miss > REACH_TOLERANCE_M, axis=-1)

    quats = np.array(quat_in, np.float32, copy=True)
    quats[:, _UPPER] = mat2quat(mat[:, _UPPER])
    return pos.astype(np.float32), quats, reach_limited
