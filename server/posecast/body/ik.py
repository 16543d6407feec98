"""Foot-contact IK (paper Sec. 3.1, post-processing) and the floor, batched over samples.

While a foot's predicted contact exceeds 0.5 the ankle is locked where the contact
began, and a two-bone solve on thigh and shin puts it there. When contact ends, the
ankle target slides linearly from the lock back to the network's own ankle over
``release_frames``, so lifting a foot never pops. The foot keeps its world
orientation, so the toe follows the ankle.

:func:`floor_ik` then lifts a foot whose ankle or toe is below the floor (``y = 0``)
back onto it with the same two-bone solve, for the shown pose only.

Everything works on world positions and rotations ``(B, 19, ...)``; the state is a
few arrays per foot, so thousands of samples step in one vectorised call.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from posecast.body.geom import swing_mat
from posecast.geometry.rotations import mat2quat, quat2mat
from posecast.skeleton import Joint

F64 = NDArray[np.floating]
D64 = NDArray[np.float64]

LEGS: tuple[tuple[Joint, Joint, Joint, Joint], ...] = (
    (Joint.LEFT_THIGH, Joint.LEFT_SHIN, Joint.LEFT_FOOT, Joint.LEFT_TOE),
    (Joint.RIGHT_THIGH, Joint.RIGHT_SHIN, Joint.RIGHT_FOOT, Joint.RIGHT_TOE),
)
CONTACT_THRESHOLD = 0.5
# A released foot blends back to the network's ankle over this many frames, and a lock
# the network's ankle has drifted this far from is released (then, still in contact,
# the foot locks again: it steps). Chosen on the validation split (docs/evaluation.md).
RELEASE_FRAMES = 20
MAX_DRIFT_M = 0.05
FLOOR_Y = 0.0  # the world floor (proto/README.md, "Conventions")
# A foot further below the floor than this is not lifted: the client's tracking space
# is not floor-level (an eye-level origin puts the feet 1.5 m down), or the body is
# too far off to fix with the legs alone. 0.4 m, chosen on the validation split: at
# 0.15 m every floor flag left (0.4 % of val frames, 4-point) was a foot 15-36 cm down,
# crouching legs the network stretched through the floor (docs/evaluation.md, "Feet").
FLOOR_MAX_LIFT_M = 0.4
# A foot less than this below the floor is left as it is: a foot resting on the floor
# sits at y = 0 up to rounding, and a two-bone solve of a straight leg moves its knee
# by about a millimetre (the reach is clamped 1 um short of full extension), so lifting
# for rounding's sake would make backends that round differently show different knees.
FLOOR_TOLERANCE_M = 1e-3
# A lifted leg whose knee is less than this off the hip-ankle line bends (partly)
# toward the thigh's forward axis (two_bone_ik's hint): a straight leg's own bend plane
# is rounding.
FLOOR_BEND_HINT_M = 0.05


def two_bone_ik(
    hip: F64,
    knee: F64,
    ankle: F64,
    target: F64,
    hint: F64 | None = None,
    hint_m: float = 0.0,
) -> tuple[F64, F64]:
    """New knee and ankle positions ``(B, 3)`` that bring the ankle to ``target``.

    Bone lengths are kept; the knee stays in the plane spanned by the hip-target line
    and the old knee, so the leg bends the way it bent. Unreachable targets are
    approached along the hip-target line with the leg straight.

    ``hint`` (directions ``(B, 3)``: the thigh's forward axis, where a knee bends) puts
    the knee on the hint's side of the hip-target line: a knee behind it (hyperextended)
    is mirrored to the front (its offset's component against the hint flipped, so a
    knee just behind the line moves just as little, and nothing jumps), because a
    target nearer the hip than the leg's length would bend such a leg backward: the
    network's nearly straight, slightly hyperextended legs showed knees bent 70 deg the
    wrong way when a locked foot drew them in (docs/evaluation.md, "Knees that bend
    backward").

    A nearly straight leg defines that plane poorly: its knee is off the line by
    ``sqrt(2 l (l1 + l2 - d))``, a millimetre for a micrometre short of full reach,
    in a direction rounding decides, and the new knee would go there. With ``hint``
    and ``hint_m`` the plane's direction is the blend ``w v + (1 - w) hint`` of the
    unit directions, ``w = (offset / hint_m)^2`` capped at 1: a straight leg bends
    toward the hint, a leg bent by ``hint_m`` or more as it bent, and nothing jumps in
    between.
    """
    l1 = np.linalg.norm(knee - hip, axis=-1, keepdims=True)
    l2 = np.linalg.norm(ankle - knee, axis=-1, keepdims=True)
    to_t = target - hip
    d = np.linalg.norm(to_t, axis=-1, keepdims=True)
    d_c = np.clip(d, np.abs(l1 - l2) + 1e-6, l1 + l2 - 1e-6)
    u = to_t / np.maximum(d, 1e-9)
    bend = knee - hip
    v = bend - np.sum(bend * u, axis=-1, keepdims=True) * u
    v_n = np.linalg.norm(v, axis=-1, keepdims=True)
    if hint is not None:
        h = hint - np.sum(hint * u, axis=-1, keepdims=True) * u
        h = h / np.maximum(np.linalg.norm(h, axis=-1, keepdims=True), 1e-9)
        back = np.minimum(np.sum(v * h, axis=-1, keepdims=True), 0.0)
        v = v - 2.0 * back * h  # a knee behind the line mirrored to its front (same |v|)
        if hint_m > 0.0:
            w = np.clip(v_n / hint_m, 0.0, 1.0) ** 2  # the old knee's say in the plane
            v = w * v / np.maximum(v_n, 1e-9) + (1.0 - w) * h
            v_n = np.linalg.norm(v, axis=-1, keepdims=True)
    # A straight leg has no bend plane: bend the knee forward (+Z of the world).
    fallback = np.broadcast_to(np.array([0.0, 0.0, 1.0]), v.shape)
    fallback = fallback - np.sum(fallback * u, axis=-1, keepdims=True) * u
    v = np.where(
        v_n > 1e-6,
        v / np.maximum(v_n, 1e-9),
        fallback / np.maximum(np.linalg.norm(fallback, axis=-1, keepdims=True), 1e-9),
    )
    cos_a = np.clip((l1**2 + d_c**2 - l2**2) / (2 * l1 * d_c), -1.0, 1.0)
    sin_a = np.sqrt(1.0 - cos_a**2)
    new_knee = hip + l1 * (cos_a * u + sin_a * v)
    new_ankle = hip + u * d_c
    return new_knee, new_ankle


def apply_leg_ik(
    world_mat: F64 | None,
    world_pos: F64,
    targets: F64,
    active: NDArray[np.bool_],
    bend_hint_m: float = 0.0,
) -> None:
    """Move each leg's ankle to ``targets (B, 2, 3)`` where ``active (B, 2)``, in place.

    Thigh and shin world rotations get the smallest swing that points their bones at
    the new knee and ankle; the foot keeps its world rotation, and the toe follows.
    With ``world_mat=None`` only positions move (the candidate pool needs no more).
    With ``world_mat`` a knee never bends away from its thigh's forward (+Z) axis (the
    ``hint`` of :func:`two_bone_ik`), and ``bend_hint_m`` is its ``hint_m``.
    """
    for side, (thigh, shin, foot, toe) in enumerate(LEGS):
        on = active[:, side]
        if not np.any(on):
            continue
        hip, knee, ankle = world_pos[on, thigh], world_pos[on, shin], world_pos[on, foot]
        hint = world_mat[on, thigh][:, :, 2] if world_mat is not None else None
        k2, a2 = two_bone_ik(hip, knee, ankle, targets[on, side], hint, bend_hint_m)
        toe_off = world_pos[on, toe] - ankle
        if world_mat is not None:
            swing_thigh = swing_mat(knee - hip, k2 - hip)  # (b, 3, 3)
            shin_dir_after_thigh = np.einsum("bij,bj->bi", swing_thigh, ankle - knee)
            swing_shin = swing_mat(shin_dir_after_thigh, a2 - k2) @ swing_thigh
            wm_t, wm_s = world_mat[on, thigh], world_mat[on, shin]
            world_mat[on, thigh] = swing_thigh @ wm_t
            world_mat[on, shin] = swing_shin @ wm_s
        world_pos[on, shin] = k2
        world_pos[on, foot] = a2
        world_pos[on, toe] = a2 + toe_off


@dataclass
class ContactIK:
    """Lock/release state of both feet for a batch of samples.

    The arrays may be views into larger engine buffers; :meth:`step` updates them in
    place. Shapes: ``locked (B, 2)``, ``lock_pos (B, 2, 3)``, ``release_left (B, 2)``
    (frames of release blending still to go), ``suppressed (B, 2)``.

    A lock the network's own ankle has drifted more than ``max_drift_m`` from is
    released early: holding it would stretch the leg straight toward a spot the body
    has left, and the knee would snap back when the contact finally ends. Once that
    release has blended back (``release_frames``), a foot still in predicted contact
    locks again where it is, so a network that slides a planted foot makes it step.
    On the validation split, holding every lock for the whole predicted contact (the
    paper's rule) made 12 % of frames implausible, releasing at 0.2 m 0.2 %; with the
    re-lock and the pelvis smoothing, 0.05 m and 20 frames of release gave both layouts'
    streamed poses a lower MPJPE and fewer plausibility flags than 0.1 m, at the same
    jitter (docs/evaluation.md).
    """

    locked: NDArray[np.bool_]
    lock_pos: F64
    release_left: NDArray[np.int64]
    release_frames: int = RELEASE_FRAMES
    suppressed: NDArray[np.bool_] | None = None
    max_drift_m: float | None = MAX_DRIFT_M

    def __post_init__(self) -> None:
        if self.suppressed is None:
            self.suppressed = np.zeros(self.locked.shape, dtype=bool)

    @classmethod
    def zeros(
        cls, n: int, release_frames: int = RELEASE_FRAMES, max_drift_m: float | None = MAX_DRIFT_M
    ) -> ContactIK:
        return cls(
            np.zeros((n, 2), dtype=bool),
            np.zeros((n, 2, 3)),
            np.zeros((n, 2), dtype=np.int64),
            release_frames,
            np.zeros((n, 2), dtype=bool),
            max_drift_m,
        )

    def step(self, world_mat: F64 | None, world_pos: F64, contact_prob: F64) -> None:
        """Post-process one frame of ``B`` poses in place: ``(B, 19, 3, 3)``, ``(B, 19, 3)``.
        With ``world_mat`` (the shown pose) a moved knee never bends away from its
        thigh's forward axis (:func:`apply_leg_ik`); without (the candidate pool)
        positions alone move, each knee in its leg's own bend plane."""
        feet = world_pos[:, [LEGS[0][2], LEGS[1][2]]]  # (B, 2, 3) network ankles
        predicted = contact_prob > CONTACT_THRESHOLD
        assert self.suppressed is not None
        # A new contact may lock again, and so may a foot whose drifted lock has finished
        # blending back to the network's ankle: it steps (locks where it now is) instead
        # of sliding with the network for the rest of the predicted contact.
        self.suppressed &= predicted & (self.release_left > 0)
        if self.max_drift_m is not None:
            drift = np.linalg.norm(feet - self.lock_pos, axis=-1)
            self.suppressed |= self.locked & predicted & (drift > self.max_drift_m)
        contact = predicted & ~self.suppressed
        starting = contact & ~self.locked
        # Lock where the ankle would be shown now: the network's ankle, or, for a foot
        # landing again mid-release, the blend it is on (locking at the network's
        # ankle there would pop the foot by the remaining lock weight).
        w = (self.release_left / max(1, self.release_frames))[..., None]
        shown = w * self.lock_pos + (1 - w) * feet
        self.lock_pos[starting] = shown[starting]
        ending = ~contact & self.locked
        self.release_left[ending] = self.release_frames
        self.release_left[contact] = 0
        self.locked[...] = contact
        releasing = self.release_left > 0
        w = (self.release_left / max(1, self.release_frames))[..., None]  # weight of the lock
        targets = np.where(contact[..., None], self.lock_pos, w * self.lock_pos + (1 - w) * feet)
        apply_leg_ik(world_mat, world_pos, targets, contact | releasing)
        self.release_left[releasing] -= 1


def floor_lift(
    world_pos: F64, floor_y: float = FLOOR_Y, max_lift_m: float = FLOOR_MAX_LIFT_M
) -> F64:
    """How far each foot ``(B, 2)`` must rise for the lower of its ankle and toe to
    reach ``floor_y``: 0 for a foot on or above it (within :data:`FLOOR_TOLERANCE_M`),
    or more than ``max_lift_m`` below."""
    lift = floor_y - _foot_low(world_pos)  # (B, 2)
    out: F64 = np.where((lift > FLOOR_TOLERANCE_M) & (lift <= max_lift_m), lift, 0.0)
    return out


def _foot_low(world_pos: F64) -> F64:
    """The height of the lower of ankle and toe of each foot, ``(..., 19, 3)`` ->
    ``(..., 2)``."""
    feet = [int(leg[2]) for leg in LEGS]
    toes = [int(leg[3]) for leg in LEGS]
    low = np.minimum(world_pos[..., feet, 1], world_pos[..., toes, 1])
    return np.asarray(low, np.float64)


def sunk(
    world_pos: F64, floor_y: float = FLOOR_Y, max_lift_m: float = FLOOR_MAX_LIFT_M
) -> NDArray[np.bool_]:
    """Whether each pose ``(..., 19, 3)`` has a foot deeper below ``floor_y`` than
    :func:`floor_ik` lifts (the lower of its ankle and toe more than ``max_lift_m``
    down): a pose the floor pass cannot stand on the floor. ``(...,)``."""
    out: NDArray[np.bool_] = np.any(floor_y - _foot_low(world_pos) > max_lift_m, axis=-1)
    return out


def floor_ik(
    world_mat: F64 | None,
    world_pos: F64,
    floor_y: float = FLOOR_Y,
    max_lift_m: float = FLOOR_MAX_LIFT_M,
    lift: F64 | None = None,
) -> NDArray[np.bool_]:
    """Lift each foot whose ankle or toe is below ``floor_y`` onto it, in place.

    The ankle target is the ankle raised by :func:`floor_lift`, so with the foot's
    world rotation kept the lower of ankle and toe ends on the floor; thigh and shin
    swing as in :func:`apply_leg_ik`, bone lengths kept (lifting brings the ankle
    nearer the hip, so the knee bends; a straight leg bends forward). Feet more than
    ``max_lift_m`` down are left alone. Returns which feet ``(B, 2)`` were lifted.
    ``lift``: :func:`floor_lift` of ``world_pos``, when the caller has it already.
    """
    if lift is None:
        lift = floor_lift(world_pos, floor_y, max_lift_m)
    active: NDArray[np.bool_] = lift > 0.0
    if np.any(active):
        targets = np.asarray(world_pos[:, [int(leg[2]) for leg in LEGS]], np.float64).copy()
        targets[..., 1] += lift
        apply_leg_ik(world_mat, world_pos, targets, active, FLOOR_BEND_HINT_M)
    return active


THIGHS_SHINS = np.array([int(j) for leg in LEGS for j in leg[:2]])  # what the leg solves turn


def floor_ik_quat(
    positions: NDArray[np.float32], rotations: NDArray[np.float32], lift: F64
) -> None:
    """:func:`floor_ik` on the shown poses, in place: positions ``(E, 19, 3)`` and world
    rotations ``(E, 19, 4)`` xyzw float32 (the thighs' and shins' change), each foot
    lifted by ``lift (E, 2)`` (:func:`floor_lift`, with the swing clearance's)."""
    rows = np.flatnonzero(lift.any(axis=1))
    if not len(rows):
        return
    pos = positions[rows].astype(np.float64)
    mat = quat2mat(rotations[rows].astype(np.float64))
    floor_ik(mat, pos, lift=lift[rows])
    positions[rows] = pos
    rotations[np.ix_(rows, THIGHS_SHINS)] = mat2quat(mat[:, THIGHS_SHINS])
