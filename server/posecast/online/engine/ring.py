"""The look-ahead ring's rows: a tick's inputs written in, a shown pelvis's neighbours read.

Each player keeps ``tau + 2`` ring rows (:class:`~posecast.online.engine.ssi.Engine`'s
slot arrays ``ring_*``): the inputs of frames ``n - tau - 1 .. n`` and the hidden
states the decoder writes for ``n + 1``. :func:`write_inputs` writes frame ``n``'s row
for the players with a frame (calibration, the held frames' velocities and the
features, all players at once); :func:`pelvis_neighbours` reads, for the players the
engine shows at frame ``e = n - tau``, their pelvis at ``e - 1`` and ``e + 1``, which
the shown pose is smoothed with (:func:`posecast.body.pipeline.show`).
"""

from __future__ import annotations

from typing import Protocol

import numpy as np
from numpy.typing import NDArray

from posecast.body.pelvis import pelvis_poses
from posecast.geometry.fk import fk_positions
from posecast.geometry.rotations import quat2mat
from posecast.online.engine.calibration import Calibration, WaistFilter, apply_all, orient_all
from posecast.online.engine.slots import SlotArrays
from posecast.online.engine.types import TrackerFrame
from posecast.skeleton import NUM_JOINTS, REST_PELVIS_HEIGHT_M, reference_offsets
from posecast.tracking.features import TRACKER_JOINT_INDEX, TrackerSlot
from posecast.tracking.layouts import Layout, LayoutSpec
from posecast.tracking.sites import SITE_JOINT_INDEX, Kind

F32 = NDArray[np.float32]
_IDENT = np.array([0.0, 0.0, 0.0, 1.0])


class Fed(Protocol):
    """What :func:`write_inputs` reads of a player (the engine's own player record)."""

    slot: int
    calibration: Calibration
    waist_filter: WaistFilter | None
    last: TrackerFrame | None  # the last real frame it sent (None: none yet)


def rest_frame(rows: int) -> TrackerFrame:
    """What a player that never sent a frame stands on (seq -1: never kept as its
    last): the reference body in its rest pose at the origin, tracked on ``rows`` rows
    (4 tracker slots, or every site; :func:`write_inputs` zeroes an inertial site's row,
    so it reads no acceleration)."""
    eye = np.broadcast_to(np.eye(3), (NUM_JOINTS, 3, 3))
    pos = fk_positions(eye, np.array([0.0, REST_PELVIS_HEIGHT_M, 0.0]), reference_offsets())
    joints = TRACKER_JOINT_INDEX if rows == len(TRACKER_JOINT_INDEX) else SITE_JOINT_INDEX
    q = np.zeros((rows, 4))
    q[:, 3] = 1.0
    return TrackerFrame(-1, pos[list(joints)], q)


def write_inputs(
    s: SlotArrays,
    k: int,
    kp: int,
    fresh: list[tuple[Fed, TrackerFrame]],
    kept: list[int],
    held: list[int],
    gaps: dict[int, int],
    layout: LayoutSpec,
    fps: float,
    rest: TrackerFrame,
) -> None:
    """Ring row ``k`` (the row before: ``kp``) of every player: ``fresh`` players step on
    their frame (``rest`` stands in for a player that never sent one), ``kept`` slots
    keep the inputs of the frame before, ``held`` slots (kept, or on ``rest``) are marked
    held. ``gaps``: per ``fresh`` row, the frames held since its last real one (its
    velocities are measured over all of them). A fresh player's ``last`` becomes its
    frame (a real one)."""
    s["ring_held"][k, : s.count] = False
    s["ring_held"][k, held] = True
    if kept:
        for name in ("ring_x", "ring_pos", "ring_quat", "ring_rootm", "ring_seq"):
            s[name][k, kept] = s[name][kp, kept]
    if not fresh:
        return
    players = [p for p, _ in fresh]
    idx = [p.slot for p in players]
    q = np.array([f.quat for _, f in fresh], dtype=np.float64)  # (M, rows, 4)
    for i, (p, f) in enumerate(fresh):
        if p.waist_filter is not None and f is not rest:  # not the stand-in
            q[i, TrackerSlot.WAIST] = p.waist_filter(q[i, TrackerSlot.WAIST])
    calibrations = [p.calibration for p in players]
    q = orient_all(calibrations, q)
    raw = np.array([f.pos for _, f in fresh], dtype=np.float64)  # (M, rows, 3)
    sites = layout.layout is Layout.SITES
    if sites:  # the rest frame's inertial rows read no acceleration
        resting = [i for i, (_, f) in enumerate(fresh) if f is rest]
        if resting:
            still = s["kinds"][[players[i].slot for i in resting]] == Kind.INERTIAL
            raw[resting] = np.where(still[..., None], 0.0, raw[resting])
    if layout.layout is Layout.HMD3:
        # No waist: keep the unused slot finite whatever the client sent.
        raw[:, TrackerSlot.WAIST], q[:, TrackerSlot.WAIST] = raw[:, TrackerSlot.HEAD], _IDENT
    cal = apply_all(calibrations, raw, q)
    # Velocities from the frame before; a player's first frame has none, and one after
    # missing frames moved over all of them (the ring held the last one).
    first = [i for i, p in enumerate(players) if p.last is None]
    prev = s["ring_pos"][kp, idx]
    prev[first] = cal[first]
    for i, gap in gaps.items():
        prev[i] = cal[i] - (cal[i] - prev[i]) / (gap + 1)
    s["ring_pos"][k, idx] = cal
    s["ring_quat"][k, idx] = q
    if not layout.predicts_root:  # the pelvis is the waist tracker's, per frame
        s["ring_rootm"][k, idx] = quat2mat(q[:, TrackerSlot.WAIST])
    s["ring_seq"][k, idx] = [f.seq for _, f in fresh]
    kinds = s["kinds"][idx] if sites else None
    s["ring_x"][k, idx] = layout.features(cal, prev, q, fps, kinds)
    for p, f in fresh:
        if f.seq >= 0:
            p.last = f


def pelvis_neighbours(
    s: SlotArrays,
    k: int,
    ring: int,
    layout: LayoutSpec,
    slots: NDArray[np.intp],
    samples: NDArray[np.intp],
    first: NDArray[np.bool_],
    own: tuple[F32, F32] | None,
    shown: tuple[F32, F32],
    waist: NDArray[np.bool_] | None,
    ahead: bool = True,
) -> tuple[NDArray[np.floating], NDArray[np.floating]]:
    """The shown pelvis's neighbours at ring row ``k`` (frame ``e``) of the players in
    ``slots``, each showing its sample of ``samples``: frames ``e - 1`` and ``e + 1``,
    rotations ``(2, E, 3, 3)`` and positions ``(2, E, 3)``, which
    :func:`~posecast.body.pipeline.show` averages the ``shown`` pelvis with (the
    look-ahead holds ``e + 1``, the ring still holds ``e - 1``). A neighbour is the
    emitted sample's own pelvis there, moved by the difference between the shown pelvis
    and that sample's at ``e`` (``own``; they differ during a transition's blend; None:
    no blend); a player's ``first`` frame stands in for its missing ``e - 1``. Without
    a delay (``ahead`` False: ``e`` is the newest frame) frame ``e`` stands in for
    ``e + 1``: the average is then ``(e - 1) + 3 e``, a quarter of a frame late, except
    that a waist tracker's position (a measurement, unlike the decoder's guess) stays
    frame ``e``'s own (chosen on the validation split, docs/latency.md)."""
    # Both neighbours in one call: frame e - 1 (or e, on a first frame), then e + 1
    # (or e, on the last rest frame before a player's first real one).
    E = len(slots)
    nxt = (k + 1) % ring if ahead else k
    last_rest = (s["ring_seq"][k, slots] < 0) & (s["ring_seq"][nxt, slots] >= 0)
    rows = np.concatenate([np.where(first, k, (k - 1) % ring), np.where(last_rest, k, nxt)])
    at = np.concatenate([slots, slots])
    m, p, _ = pelvis_poses(
        s["ring_pos"][rows, at],
        s["ring_quat"][rows, at],
        s["ring_rootm"][rows, at],
        s["ring_root"][rows, at, np.concatenate([samples, samples])]
        if layout.predicts_root
        else None,
        1,
        None if waist is None else np.concatenate([waist, waist]),
    )
    mats: NDArray[np.floating] = m.reshape(2, E, 3, 3)
    places: NDArray[np.floating] = p.reshape(2, E, 3)
    if own is not None:  # a blend: move the sample's own motion onto the shown pelvis
        mats = (mats @ np.swapaxes(own[0], -1, -2)) @ shown[0]
        places = shown[1] + (places - own[1])
    if not ahead:  # a waist tracker's position is the newest frame's, unsmoothed
        tracked = np.ones(E, np.bool_) if not layout.predicts_root else waist
        if tracked is not None and tracked.any():
            places = places.copy()
            places[:, tracked] = np.asarray(shown[1], places.dtype)[tracked]
    return mats, places
