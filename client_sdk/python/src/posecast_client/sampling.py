"""The jitter buffer's samples, made in batches (pure array math, no rules): what
:mod:`posecast_client.interp` decides per player, made here for every player at once.

A buffer decides a display frame's sample without touching an array, as a
:class:`SamplePlan`: positions ``base + (x1 - x0) * s`` and rotations
``slerp(q0, q1, u)``, each operand a kept :class:`Entry`. Interpolation (``a`` to
``b`` at ``u``), extrapolation (``a`` on from ``p``) and holding are all of that form,
so :func:`make_samples` makes the samples of many players with one batch of array
operations per pose shape: a display frame of eight players costs about what one
player's does. :func:`fade` does the same for the corrections rule 5 fades out.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

import numpy as np
from numpy.typing import NDArray

from posecast_client.rotations import quat_mul

F64 = NDArray[np.float64]
Mode = Literal["interpolate", "extrapolate", "hold"]
ROOT = 0  # PELVIS: the joint whose jump is a teleport
_IDENTITY = np.array([0.0, 0.0, 0.0, 1.0])


@dataclass(slots=True, eq=False)
class Entry:
    """A pose a buffer keeps (its arrays as pushed)."""

    t: float
    seq: int
    keyframe: bool
    positions: F64
    rotations: F64 | None
    root: tuple[float, ...] = ()  # positions[ROOT], for the teleport rule
    seen: bool = False  # a query has run since it was pushed (its need is counted)
    snaps: bool = False  # it starts a segment after the entry before it (rule 2)


@dataclass(slots=True, eq=False)
class SamplePlan:
    """A sample at ``tau`` as the rules decide it, before any array is touched:
    positions ``base + (x1 - x0) * s``, rotations ``slerp(q0, q1, u)`` (``None``: no
    rotations), each operand a kept entry's. Two plans with the same operands and
    weights give the same sample, bit for bit."""

    tau: float
    base: Entry  # the pose whose seq is shown
    x1: Entry
    x0: Entry
    s: float
    q0: Entry | None
    q1: Entry | None
    u: float
    mode: Mode

    def same(self, other: SamplePlan) -> bool:
        return (
            self.base is other.base
            and self.x1 is other.x1
            and self.x0 is other.x0
            and self.q0 is other.q0
            and self.q1 is other.q1
            and self.s == other.s
            and self.u == other.u
            and self.mode == other.mode
        )


@dataclass(slots=True)
class Correction:
    """A correction fading out (rule 5): added to a raw sample's positions ``(J, 3)``,
    and a world rotation ``(J, 4)`` turning its rotations (``None``: none)."""

    dpos: F64
    turn: F64 | None


def quat_slerp(q0: F64, q1: F64, u: float | F64) -> F64:
    """Spherical interpolation ``(..., 4)`` xyzw on the shorter arc; ``u`` outside
    ``[0, 1]`` extrapolates along the same great circle. Inputs need not be unit.
    ``u`` is a float, or an array that broadcasts against ``(..., 1)`` (a weight per
    pose of a batch ``(n, J, 4)``: ``u`` of shape ``(n, 1, 1)``)."""
    a = q0 / np.sqrt((q0 * q0).sum(-1, keepdims=True))
    b = q1 / np.sqrt((q1 * q1).sum(-1, keepdims=True))
    dot = (a * b).sum(-1, keepdims=True)
    b = b * np.where(dot < 0.0, -1.0, 1.0)  # the same rotation, on a's hemisphere
    cos = np.minimum(np.abs(dot), 1.0)
    omega = np.arccos(cos)  # (..., 1) half the angle between them
    sin = np.sin(omega)
    small = sin < 1e-6  # nearly equal: the sines cancel badly, lerp is exact enough
    safe = np.where(small, 1.0, sin)
    w0 = np.where(small, 1.0 - u, np.sin((1.0 - u) * omega) / safe)
    w1 = np.where(small, u, np.sin(u * omega) / safe)
    out: F64 = w0 * a + w1 * b
    out /= np.sqrt((out * out).sum(-1, keepdims=True))
    return out


def _rotations(e: Entry | None) -> F64:
    assert e is not None and e.rotations is not None  # a plan with rotations has them
    return e.rotations


def make_samples(plans: list[SamplePlan]) -> list[tuple[F64, F64 | None]]:
    """The samples of ``plans``: the plans of poses of one shape (and all with or all
    without rotations) in one batch of array operations, whatever their count: a
    display frame of many players costs about what one player's does."""
    out: list[tuple[F64, F64 | None]] = [None] * len(plans)  # type: ignore[list-item]
    groups: dict[tuple[tuple[int, ...], bool], list[int]] = {}
    for k, p in enumerate(plans):
        groups.setdefault((p.base.positions.shape, p.q0 is not None), []).append(k)
    for (_, rotated), ks in groups.items():
        if len(ks) == 1:
            p = plans[ks[0]]
            pos = p.base.positions + (p.x1.positions - p.x0.positions) * p.s
            rot = quat_slerp(_rotations(p.q0), _rotations(p.q1), p.u) if rotated else None
            out[ks[0]] = (pos, rot)
            continue
        g = [plans[k] for k in ks]
        s = np.array([p.s for p in g])[:, None, None]  # (n, 1, 1)
        base = np.stack([p.base.positions for p in g])  # (n, J, 3)
        x1 = np.stack([p.x1.positions for p in g])
        x0 = np.stack([p.x0.positions for p in g])
        positions = base + (x1 - x0) * s
        rots: list[F64 | None] = [None] * len(g)
        if rotated:
            q0 = np.stack([_rotations(p.q0) for p in g])  # (n, J, 4)
            q1 = np.stack([_rotations(p.q1) for p in g])
            u = np.array([p.u for p in g])[:, None, None]
            rots = list(quat_slerp(q0, q1, u))
        for j, k in enumerate(ks):
            out[k] = (positions[j], rots[j])
    return out


NEGLIGIBLE = 1e-12  # a correction smaller than this (metres, quaternion parts) is over


def fade(
    items: list[tuple[Correction, float, F64 | None]],
) -> list[tuple[Correction, F64 | None] | None]:
    """Each correction ``(correction, k, rotations)`` with the share ``k`` of it left,
    for a raw sample with ``rotations`` ``(J, 4)`` (or ``None``): the correction now
    and the raw rotations it turns (``None``: no turn), or ``None`` where it has faded
    under :data:`NEGLIGIBLE`. Corrections of one shape are faded in one batch."""
    out: list[tuple[Correction, F64 | None] | None] = [None] * len(items)
    groups: dict[tuple[tuple[int, ...], bool], list[int]] = {}
    for n, (c, _, rot) in enumerate(items):
        groups.setdefault((c.dpos.shape, c.turn is not None and rot is not None), []).append(n)
    for (_, turned), ns in groups.items():
        ks = np.array([items[n][1] for n in ns])  # (n,)
        dpos = np.stack([items[n][0].dpos for n in ns]) * ks[:, None, None]  # (n, J, 3)
        size = np.abs(dpos).max(axis=(1, 2)) if dpos.size else np.zeros(len(ns))
        turns: F64 | None = None
        rots: F64 | None = None
        if turned:
            prev = np.stack([_turn(items[n][0]) for n in ns])  # (n, J, 4)
            turns = quat_slerp(np.broadcast_to(_IDENTITY, prev.shape), prev, ks[:, None, None])
            size = np.maximum(size, np.abs(turns[..., :3]).max(axis=(1, 2)))
            rots = quat_mul(turns, np.stack([_raw_rotations(items[n][2]) for n in ns]))
        for j, n in enumerate(ns):
            if size[j] >= NEGLIGIBLE:
                turn = None if turns is None else turns[j]
                out[n] = (Correction(dpos[j], turn), None if rots is None else rots[j])
    return out


def _turn(c: Correction) -> F64:
    assert c.turn is not None
    return c.turn


def _raw_rotations(rot: F64 | None) -> F64:
    assert rot is not None
    return rot
