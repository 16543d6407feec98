"""The shown pose: one function runs every pass, in order, on a batch of players.

:func:`show` turns one decoded sample per player (the network's rotations and contacts,
its pelvis, its trackers) into the body that is streamed. The engine calls it once a
tick on the ``E`` players it emits (``posecast.online.engine.ssi``); the evaluation's
single-sample variants call it frame by frame over their clips
(``posecast.offline.evaluation.runner``), so what they measure is what is streamed.
The passes, in their order:

1. the pelvis averaged with its neighbours' (:mod:`posecast.body.pelvis`);
2. a guessed pelvis (no waist tracker) leans toward the headset and moves toward
   trackers beyond reach (:func:`~posecast.body.upper_ik.lean_root`,
   :func:`~posecast.body.upper_ik.reach_root`), eased frame to frame;
3. FK and the display contact IK (``Passes.emit``, :mod:`posecast.body.ik`);
4. a planted toe slides no faster than a bound (:mod:`posecast.body.plant`; only
   with the floor pass);
5. a held foot the other leg runs into gives way (:mod:`posecast.body.apart`);
6. the floor pass and the swing clearance (:mod:`posecast.body.clearance`);
7. a tracker set's feet and knees onto their trackers (:mod:`posecast.body.leg_ik`);
8. the knees onto their hinges (``Passes.hinge``, :mod:`posecast.body.hinge`);
9. head and hands onto their trackers (``Passes.upper_body``,
   :mod:`posecast.body.upper_ik`);
10. the elbows onto their hinges.

Each pass has a switch in ``cfg`` (:class:`Settings`: the engine's ``EngineConfig``).
What a player carries from frame to frame (its contact locks, its toes' speeds, the
reach's eased move) is a :class:`ShownState`, updated in place. Steps 3, 8 and 9 run in
``passes`` (:mod:`posecast.body.passes`: numpy, or a backend's C); the rest is numpy.
Everything is in calibrated canonical-body metres; the caller divides by the user's
scale.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any, Protocol

import numpy as np
from numpy.typing import NDArray

from posecast.body.apart import keep_apart_quat
from posecast.body.batch_fk import fk32
from posecast.body.clearance import TOES, clearance_lift, toe_speed
from posecast.body.hinge import ELBOW_LIMBS, KNEE_LIMBS
from posecast.body.ik import floor_ik_quat, floor_lift
from posecast.body.leg_ik import senses_legs, solve_legs, tracks_legs
from posecast.body.passes import Passes, PoolIK
from posecast.body.pelvis import smooth_pelvis
from posecast.body.plant import plant_toes
from posecast.body.upper_ik import (
    LEAN_JOINTS,
    SPAN_SHARE,
    ease_reach,
    lean_root,
    reach_root,
    turn_pelvis,
)
from posecast.skeleton import Joint
from posecast.tracking.features import TrackerSlot

F32 = NDArray[np.float32]
F64 = NDArray[np.float64]


class Settings(Protocol):
    """The switches of :func:`show` (``posecast.online.engine.config.EngineConfig``
    documents each; it is the one config that carries them)."""

    @property
    def fps(self) -> float: ...
    @property
    def pelvis_smoothing(self) -> bool: ...
    @property
    def leans(self) -> bool: ...
    @property
    def reaches(self) -> bool: ...
    @property
    def torso_span(self) -> bool: ...
    @property
    def legs_apart(self) -> bool: ...
    @property
    def floor_ik(self) -> bool: ...
    @property
    def swing_clearance(self) -> bool: ...
    @property
    def planted_toes(self) -> bool: ...
    @property
    def upper_body_ik(self) -> bool: ...
    @property
    def knee_hinge(self) -> bool: ...
    @property
    def elbow_hinge(self) -> bool: ...
    @property
    def wrist_elbow(self) -> float: ...


@dataclass
class Decoded:
    """One frame ``e`` of ``E`` players: the sample each shows, and where it stands.

    Attributes:
        rotations: the network's 6D rotations ``(E, 108)`` float32.
        contacts: its contact probabilities ``(E, 2)`` float32.
        root_mat, root_pos: the pelvis at frame ``e``, ``(E, 3, 3)`` and ``(E, 3)``
            float32 (:func:`posecast.body.pelvis.pelvis_poses`).
        tracker_pos, tracker_quat: the calibrated trackers ``(E, rows, 3)`` and
            ``(E, rows, 4)`` float64, slot order (a tracker set: its ten sites).
        first: ``(E,)`` whether frame ``e`` is the player's first (no frame before it
            to ease or measure a speed from).
        neighbours: the pelvis at frames ``e - 1`` and ``e + 1``, rotations
            ``(2, E, 3, 3)`` and positions ``(2, E, 3)`` (a missing one: frame ``e``'s
            again), for the smoothing; ``None``: not smoothed.
        free: ``(E,)`` whether each pelvis is the decoder's guess (no positional
            waist); ``None``: none is.
        kinds: a tracker set's site kinds ``(E, 10)``; ``None`` for the named layouts.
    """

    rotations: F32
    contacts: F32
    root_mat: F32
    root_pos: F32
    tracker_pos: F64
    tracker_quat: F64
    first: NDArray[np.bool_]
    neighbours: tuple[NDArray[np.floating], NDArray[np.floating]] | None = None
    free: NDArray[np.bool_] | None = None
    kinds: NDArray[np.int8] | None = None


@dataclass
class ShownState:
    """What each of ``E`` players' shown pose carries to its next frame (arrays,
    updated in place): the display contact IK's locks (``ik``), both toes' horizontal
    positions ``toe_xz (E, 2, 2)`` and averaged speeds ``toe_speed (E, 2)`` (the swing
    clearance), the eased move of a guessed pelvis ``reach (E, 3)``, and the planted
    toes' shown horizontal positions ``plant_xz (E, 2, 2)`` and offsets from the
    network's ``plant_offset (E, 2, 2)`` (:mod:`posecast.body.plant`). A player's first
    frame reads none of the last five."""

    ik: PoolIK
    toe_xz: F64
    toe_speed: F64
    reach: F64
    plant_xz: F64
    plant_offset: F64

    @classmethod
    def zeros(cls, n: int) -> ShownState:
        """The state of ``n`` players before their first frame."""
        z = np.zeros
        return cls(PoolIK.zeros(n), z((n, 2, 2)), z((n, 2)), z((n, 3)), z((n, 2, 2)), z((n, 2, 2)))

    @classmethod
    def of(cls, arrays: Sequence[NDArray[Any]]) -> ShownState:
        """The state made of :meth:`arrays`' nine arrays, in their order."""
        locked, lock_pos, release, suppressed, toe_xz, toe_speed, reach, xz, off = arrays
        ik = PoolIK(locked, lock_pos, release, suppressed)
        return cls(ik, toe_xz, toe_speed, reach, xz, off)

    def arrays(self) -> tuple[NDArray[Any], ...]:
        """Every array: the contact IK's four (:class:`PoolIK`'s order), then
        ``toe_xz``, ``toe_speed``, ``reach``, ``plant_xz`` and ``plant_offset``."""
        ik = self.ik
        return (
            ik.locked,
            ik.lock_pos,
            ik.release,
            ik.suppressed,
            self.toe_xz,
            self.toe_speed,
            self.reach,
            self.plant_xz,
            self.plant_offset,
        )


@dataclass
class Shown:
    """The streamed body of ``E`` players: world ``positions (E, 19, 3)`` and
    ``rotations (E, 19, 4)`` xyzw, float32, and per player whether a tracker pass left
    an effector more than 1 mm from its tracker (``reach_limited (E,)``)."""

    positions: F32
    rotations: F32
    reach_limited: NDArray[np.bool_]


def show(batch: Decoded, state: ShownState, cfg: Settings, passes: Passes) -> Shown:
    """The shown poses of ``batch`` (see the module docstring for the passes); ``state``
    moves on to this frame."""
    rot, root_mat, root_pos = batch.rotations, batch.root_mat, batch.root_pos
    if cfg.pelvis_smoothing and batch.neighbours is not None:
        mats, places = batch.neighbours
        m, p = smooth_pelvis((mats[0], root_mat, mats[1]), (places[0], root_pos, places[1]))
        root_mat, root_pos = m.astype(np.float32), p.astype(np.float32)
    free = batch.free
    if (cfg.reaches or cfg.leans) and free is not None and free.any():
        rot, root_mat, root_pos = _guessed_pelvis(batch, state, cfg, rot, root_mat, root_pos)
    wp, rotations = passes.emit(rot, batch.contacts, root_mat, root_pos, state.ik)
    if cfg.floor_ik and cfg.planted_toes:
        plant_toes(
            wp, rotations, batch.contacts, state.plant_xz, state.plant_offset, batch.first, cfg.fps
        )
    if cfg.legs_apart:
        keep_apart_quat(wp, rotations, rot, root_mat, root_pos)
    if cfg.floor_ik:
        lift = floor_lift(wp)
        if cfg.swing_clearance:
            speed = _toe_speeds(wp, state, batch.first, cfg.fps)
            lift = np.maximum(lift, clearance_lift(wp, speed))
        floor_ik_quat(wp, rotations, lift)
    pos, quat, kinds = batch.tracker_pos, batch.tracker_quat, batch.kinds
    reach_limited = np.zeros(len(wp), np.bool_)
    if cfg.upper_body_ik and kinds is not None:
        # A tracker set's positional feet and knees: the legs onto their trackers.
        legs = np.flatnonzero(tracks_legs(kinds))
        if len(legs):
            wp[legs], rotations[legs], reach_limited[legs] = solve_legs(
                wp[legs], rotations[legs], pos[legs], quat[legs], kinds[legs]
            )
    if cfg.knee_hinge:
        passes.hinge(wp, rotations, KNEE_LIMBS)
    if cfg.upper_body_ik:
        # Head and hands onto their (calibrated) trackers (a pelvis from the decoder
        # may follow the head).
        wp, rotations, upper_limited = passes.upper_body(
            wp, rotations, pos, quat, free, cfg.wrist_elbow
        )
        reach_limited |= upper_limited
    if cfg.elbow_hinge:
        passes.hinge(wp, rotations, ELBOW_LIMBS)
    return Shown(wp, rotations, reach_limited)


def _guessed_pelvis(
    batch: Decoded, state: ShownState, cfg: Settings, rot: F32, root_mat: F32, root_pos: F32
) -> tuple[F32, F32, F32]:
    """The network's pose on a guessed pelvis leant so that the line to the head meets
    the headset (``lean_root``), then moved toward the trackers it cannot reach
    (``reach_root``, eased: ``state.reach``), before the display IK plants the feet:
    the new ``(rot, root_mat, root_pos)``."""
    assert batch.free is not None
    rows = np.flatnonzero(batch.free)
    pos = batch.tracker_pos
    _, near32 = fk32(rot[rows], root_mat[rows], root_pos[rows], False, LEAN_JOINTS)
    near: NDArray[np.floating] = near32
    # A set that senses its legs keeps its hips as they are and its height.
    sensed = senses_legs(batch.kinds[rows]) if batch.kinds is not None else None
    if cfg.leans:
        head = near[:, Joint.HEAD]
        turn = lean_root(root_pos[rows], head, pos[rows, TrackerSlot.HEAD])
        if sensed is not None:
            turn[sensed] = np.eye(3)
        rot, root_mat = rot.copy(), root_mat.copy()
        rot[rows], root_mat[rows] = turn_pelvis(rot[rows], root_mat[rows], turn)
        pivot = root_pos[rows, None].astype(np.float64)
        lean = list(LEAN_JOINTS)
        # Only LEAN_JOINTS' rows of fk32's output are defined: the others are whatever
        # the buffer held, which a cast to float64 may trip on (a signalling NaN raises
        # "invalid value"), so they are not cast.
        leant = np.zeros(near.shape, np.float64)
        leant[:, lean] = pivot + np.einsum("eab,ekb->eka", turn, near[:, lean] - pivot)
        near = leant
    if cfg.reaches:
        span = None if sensed is None else np.where(sensed, 0.0, SPAN_SHARE)
        target = reach_root(near, pos[rows], span if cfg.torso_span else 0.0)
        first = batch.first[rows]
        eased = ease_reach(state.reach[rows], target)
        eased[first] = target[first]  # a first frame takes the target as it is
        state.reach[rows] = eased
        root_pos = root_pos.copy()
        root_pos[rows] += eased.astype(np.float32)
    return rot, root_mat, root_pos


def _toe_speeds(
    wp: F32, state: ShownState, first: NDArray[np.bool_], fps: float
) -> NDArray[np.floating]:
    """The averaged toe speeds ``(E, 2)`` (:func:`~posecast.body.clearance.toe_speed`)
    of the shown poses ``wp`` before any lift; ``state`` moves on to this frame. A
    player's first frame starts at rest."""
    xz = wp[:, TOES][:, :, [0, 2]].astype(np.float64)
    prev = np.where(first[:, None, None], xz, state.toe_xz)
    was = np.where(first[:, None], 0.0, state.toe_speed)
    speed = toe_speed(prev, xz, was, fps)
    state.toe_xz[...], state.toe_speed[...] = xz, speed
    return speed
