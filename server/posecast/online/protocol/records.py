"""Protocol v2 pose records: keyframes and closed-loop deltas (pure: numpy in, bytes out).

A v2 ``poses`` message carries one tick's poses for one client as the concatenation
of records (``proto/README.md``, "Pose records"). Each record describes one avatar
by 19 *items*: the ``PELVIS`` world rotation, then the 18 local joint rotations in
joint order (joint ``j``'s rotation relative to its parent), plus the ``PELVIS``
world position (the *root*)::

    record   = avatar id (LEB128) | flags (u8) | keyframe body | delta body
    keyframe = seq (u32 LE) | root (3 x i32 LE, 0.1 mm) | 19 x smallest-three (48 bits)
    delta    = seq delta (u8, 1..255) | bitstream: root item, then the 19 rotation items,
               each a 2-bit width class and, unless the class is 0, 3 signed components

A delta is relative to the **reference**: the state the client reconstructed from
the previous record of that avatar sent to it. Per item the client keeps the last
step ``v`` (3 ints; zero after a keyframe); a delta's component ``r`` gives the new
step ``d = v + r`` (constant-velocity prediction plus residual) and::

    root  <- root + d                      (0.1 mm)
    rot_i <- normalise(rot_i * exp(d * ROT_STEP_RAD))   (d is a rotation vector)

The encoder here keeps exactly that state (:class:`Recon`), so quantisation errors
never accumulate: every reconstructed local rotation is within ``sqrt(3)/2 *
ROT_STEP_RAD`` (0.097 deg, plus a second-order term) of the engine's, and the root
within 0.05 mm per axis. A record that does not fit (a residual wider than its
widest class, a seq jump outside 1..255) is sent as a keyframe instead.

This module is the encoder; the items, byte layouts and :class:`Recon` are in
:mod:`~posecast.online.protocol.record_state`, the reference decoder in
:mod:`~posecast.online.protocol.record_decode`, and their names stay importable here.

Glossary as in :mod:`posecast.geometry.rotations`: quaternions xyzw, Hamilton product.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from types import ModuleType
from typing import Any

import numpy as np
from numpy.typing import NDArray

from posecast.errors import OutOfRangeError
from posecast.geometry.rotations import quat_conj, quat_mul
from posecast.online.protocol import record_decode, record_state
from posecast.online.protocol.messages import UINT32_MAX
from posecast.online.protocol.record_decode import *  # noqa: F403 (re-exported, as __all__ says)
from posecast.online.protocol.record_state import *  # noqa: F403 (re-exported, as __all__ says)
from posecast.online.protocol.record_state import (
    F64,
    FLAG_KEYFRAME,
    FLAG_REACH_LIMITED,
    MAX_DELTA_BYTES,
    NUM_ITEMS,
    ROOT_MAX,
    ROOT_UNIT_M,
    ROOT_WIDTHS,
    ROT_STEP_RAD,
    ROT_WIDTHS,
    Recon,
    normalise,
    quat2rotvec,
    rotvec2quat,
    smallest3_pack,
    smallest3_unpack,
    world2items,
)
from posecast.skeleton import NUM_JOINTS, PARENTS

_native: ModuleType | None
try:  # the C encoder of deltas (optional, as the native engine backend is)
    from posecast import _native
except ImportError:  # pragma: no cover - an install without a C compiler
    _native = None

__all__ = [  # the encoder's own names; the record names stay importable from here
    "DELTA_ENCODER",
    "DELTA_ENCODERS",
    "PoseState",
    "encode_delta",
    "encode_deltas",
    "encode_many",
]
__all__ += record_state.__all__
__all__ += record_decode.__all__

_PARENTS = np.array(PARENTS[1:])


@dataclass(eq=False)
class PoseState:
    """One engine pose ready for v2 encoding, made once per pose in the engine thread.

    Encodings are cached on it: a keyframe, and one delta per reference object, so
    all the clients that share a reference get the same bytes for one encoding.
    """

    player: str
    seq: int
    t: float  # server time of the tick that made it
    root: tuple[int, int, int]  # PELVIS world position, 0.1 mm
    items: F64  # (19, 4) PELVIS world rotation, then the local rotations
    world: F64  # (19, 4) the world rotations (what deltas aim at)
    scale: float = 1.0  # the calibration the engine used (canonical per user metre)
    reach_limited: bool = False
    _keyframe: tuple[bytes, Recon] | None = None
    _deltas: dict[int, tuple[Recon, bytes | None, Recon | None]] = field(default_factory=dict)

    @classmethod
    def from_engine(
        cls,
        player: str,
        seq: int,
        t: float,
        positions: F64,
        rotations: F64,
        scale: float = 1.0,
        reach_limited: bool = False,
    ) -> PoseState:
        """From world ``positions (19, 3)`` metres and world ``rotations (19, 4)``;
        OUT_OF_RANGE when the pelvis is beyond +-1000 m."""
        q = np.asarray(rotations, dtype=np.float64)
        root = np.rint(np.asarray(positions[0], dtype=np.float64) / ROOT_UNIT_M)
        if not (np.abs(root) <= ROOT_MAX).all():
            raise OutOfRangeError("the pelvis is beyond +-1000 m", field="root")
        r = root.astype(np.int64).tolist()
        w = normalise(q)
        return cls(player, seq, t, (r[0], r[1], r[2]), world2items(w), w, scale, reach_limited)

    @classmethod
    def from_world(
        cls,
        player: str,
        seq: int,
        t: float,
        root: tuple[int, int, int],
        world: F64,
        scale: float = 1.0,
        reach_limited: bool = False,
    ) -> PoseState:
        """From the pelvis in 0.1 mm steps and world ``rotations (19, 4)`` (a pose another
        node made); ``ValueError`` when the root is beyond +-1000 m or a rotation is not
        a unit quaternion's."""
        if not all(abs(c) <= ROOT_MAX for c in root):
            raise ValueError("the pelvis is beyond +-1000 m")
        w = normalise(np.asarray(world, dtype=np.float64))
        if not np.isfinite(w).all():
            raise ValueError("a rotation is not finite")
        return cls(player, seq, t, root, world2items(w), w, scale, reach_limited)

    @classmethod
    def batch(
        cls,
        players: list[str],
        seqs: list[int],
        t: float,
        positions: NDArray[np.floating[Any]],
        rotations: NDArray[np.floating[Any]],
        scales: list[float],
        reach_limited: list[bool],
    ) -> list[PoseState | None]:
        """:meth:`from_engine` of ``E`` poses at once (``positions (E, 19, 3)``,
        ``rotations (E, 19, 4)``); ``None`` for a pose whose pelvis is beyond +-1000 m."""
        q = normalise(np.asarray(rotations, dtype=np.float64))  # (E, 19, 4)
        items = q.copy()
        items[:, 1:] = quat_mul(quat_conj(q[:, _PARENTS]), q[:, 1:])
        root = np.rint(np.asarray(positions, dtype=np.float64)[:, 0] / ROOT_UNIT_M)  # (E, 3)
        inside: NDArray[np.bool_] = np.all(np.abs(root) <= ROOT_MAX, axis=1)
        ok: list[bool] = inside.tolist()
        roots: list[list[int]] = np.where(np.isfinite(root), root, 0).astype(np.int64).tolist()
        return [
            cls(
                players[i],
                seqs[i],
                t,
                (r[0], r[1], r[2]),
                items[i],
                q[i],
                scales[i],
                reach_limited[i],
            )
            if ok[i]
            else None
            for i, r in enumerate(roots)
        ]

    @property
    def flags(self) -> int:
        return FLAG_REACH_LIMITED if self.reach_limited else 0

    def keyframe(self) -> tuple[bytes, Recon]:
        """The keyframe body (flags onwards) and what a client reconstructs from it."""
        if self._keyframe is None:
            rot = smallest3_pack(self.items)
            body = (
                bytes([self.flags | FLAG_KEYFRAME])
                + self.seq.to_bytes(4, "little")
                + b"".join(v.to_bytes(4, "little", signed=True) for v in self.root)
                + rot
            )
            self._keyframe = (body, Recon(self.seq, self.root, smallest3_unpack(rot)))
        return self._keyframe

    def delta(self, ref: Recon) -> tuple[bytes, Recon] | None:
        """The delta body against ``ref`` and the new reference, or ``None`` when the
        pose does not fit a delta (send a keyframe)."""
        hit = self._deltas.get(id(ref))
        if hit is not None and hit[0] is ref:
            body, recon = hit[1], hit[2]
        else:
            got = encode_delta(ref, self.seq, self.root, self.world, self.flags)
            body, recon = (None, None) if got is None else got
            self._deltas[id(ref)] = (ref, body, recon)  # holds ref: its id stays unique
        return None if body is None or recon is None else (body, recon)


def encode_many(pairs: list[tuple[PoseState, Recon]]) -> list[tuple[bytes, Recon] | None]:
    """:meth:`PoseState.delta` of many (pose, reference) pairs, the uncached ones in one
    :func:`encode_deltas` call: how a tick's deltas for every client are made."""
    todo: list[tuple[PoseState, Recon]] = []
    seen: set[tuple[int, int]] = set()
    for state, ref in pairs:
        hit = state._deltas.get(id(ref))
        key = (id(state), id(ref))
        if (hit is None or hit[0] is not ref) and key not in seen:
            seen.add(key)
            todo.append((state, ref))
    if todo:
        got = encode_deltas(
            [r for _, r in todo],
            [s.seq for s, _ in todo],
            [s.root for s, _ in todo],
            np.stack([s.world for s, _ in todo]),
            [s.flags for s, _ in todo],
        )
        for (state, ref), res in zip(todo, got, strict=True):
            state._deltas[id(ref)] = (ref, None, None) if res is None else (ref, *res)
    return [state.delta(ref) for state, ref in pairs]


# --- deltas --------------------------------------------------------------------------------


_ITEM_WIDTHS = np.array([ROOT_WIDTHS, *([ROT_WIDTHS] * NUM_ITEMS)], np.int64)  # (20, 4)
_BIT = np.arange(ROOT_WIDTHS[-1], dtype=np.int64)  # bit positions of the widest component


def encode_delta(
    ref: Recon, seq: int, root: tuple[int, int, int], world: F64, flags: int = 0
) -> tuple[bytes, Recon] | None:
    """A delta body (flags onwards) taking ``ref`` to the pose with world rotations
    ``world (19, 4)``, and the new reference; ``None`` when it does not fit."""
    return encode_deltas([ref], [seq], [root], world[None], [flags])[0]


def _levels() -> list[NDArray[np.intp]]:
    depth = [0] * NUM_JOINTS
    for j in range(1, NUM_JOINTS):
        depth[j] = depth[PARENTS[j]] + 1
    return [
        np.array([j for j in range(NUM_JOINTS) if depth[j] == d]) for d in range(max(depth) + 1)
    ]


_PARENTS_ALL = np.array(PARENTS, np.int64)  # (19,) -1 for PELVIS
DELTA_ENCODERS: tuple[str, ...] = ("native", "numpy") if _native is not None else ("numpy",)
DELTA_ENCODER = DELTA_ENCODERS[0]  # the encoder the server uses: C where it loads
_LEVELS = _levels()  # joints by depth: [PELVIS], [SPINE, LEFT_THIGH, RIGHT_THIGH], ...
_PARENT_OF = np.array([max(p, 0) for p in PARENTS])


def encode_deltas(
    refs: list[Recon],
    seqs: list[int],
    roots: list[tuple[int, int, int]],
    world: F64,
    flags: list[int],
    encoder: str | None = None,
) -> list[tuple[bytes, Recon] | None]:
    """:func:`encode_delta` of ``M`` poses at once (``world (M, 19, 4)``), by the
    encoder named (``DELTA_ENCODERS``; by default :data:`DELTA_ENCODER`, ``native``
    where the C extension loads)."""
    name = DELTA_ENCODER if encoder is None else encoder
    if name not in DELTA_ENCODERS:  # native too, where the extension did not load
        raise ValueError(f"no delta encoder {name!r}: one of {', '.join(DELTA_ENCODERS)}")
    if name == "native":
        return _encode_deltas_native(refs, seqs, roots, world, flags)
    return _encode_deltas_numpy(refs, seqs, roots, world, flags)


def _encode_deltas_native(
    refs: list[Recon],
    seqs: list[int],
    roots: list[tuple[int, int, int]],
    world: F64,
    flags: list[int],
) -> list[tuple[bytes, Recon] | None]:
    """:func:`_encode_deltas_numpy` in C (``server/native/pc_records.c``), the same
    operations in the same order, one pose at a time; the GIL is released meanwhile."""
    assert _native is not None
    m = len(refs)
    if not m:
        return []
    new_items = np.empty((m, NUM_ITEMS, 4))
    d_rot = np.empty((m, NUM_ITEMS, 3), np.int64)
    body = np.empty((m, MAX_DELTA_BYTES), np.uint8)
    length = np.empty(m, np.int64)
    _native.encode_deltas(
        _PARENTS_ALL,
        np.array(seqs, np.int64),
        np.array([r.seq for r in refs], np.int64),
        np.array(flags, np.int64),
        np.stack([r.items for r in refs]),
        np.stack([r.step_rot for r in refs]).astype(np.int64, copy=False),
        np.ascontiguousarray(world, dtype=np.float64),
        np.array([r.root for r in refs], np.int64),
        np.array([r.step_root for r in refs], np.int64),
        np.array(roots, np.int64),
        new_items,
        d_rot,
        body,
        length,
    )
    blob = body.tobytes()
    lens: list[int] = length.tolist()
    out: list[tuple[bytes, Recon] | None] = []
    for i, (ref, n) in enumerate(zip(refs, lens, strict=True)):
        if not n:
            out.append(None)
            continue
        root = roots[i]
        d = (root[0] - ref.root[0], root[1] - ref.root[1], root[2] - ref.root[2])
        at = i * MAX_DELTA_BYTES
        out.append((blob[at : at + n], Recon(seqs[i], root, new_items[i], d, d_rot[i])))
    return out


def _encode_deltas_numpy(
    refs: list[Recon],
    seqs: list[int],
    roots: list[tuple[int, int, int]],
    world: F64,
    flags: list[int],
) -> list[tuple[bytes, Recon] | None]:
    """The reference encoder: one numpy pass for the residuals, the width classes and
    the bit packing of all ``M`` poses.

    Each item's residual is taken against the prediction ``q_ref * exp(v * step)`` and
    aims at the *reconstructed* parent: item ``j`` targets ``conj(W'[parent]) *
    W[j]``, where ``W'`` are the world rotations the client will rebuild. So a joint's
    world rotation carries only its own quantisation error, never its ancestors'
    (the client's FK drifts no further down the chain than one step's error). Joints
    are encoded level by level down the tree, every joint of a level at once.
    """
    m = len(refs)
    ref_items = np.stack([r.items for r in refs])  # (M, 19, 4)
    step_rot = np.stack([r.step_rot for r in refs])  # (M, 19, 3)
    new_items = np.empty_like(ref_items)
    new_world = np.empty_like(ref_items)
    r_rot = np.empty_like(step_rot)
    # Every item's prediction at once: it depends on the references alone.
    pred_all = quat_mul(ref_items, rotvec2quat(step_rot.astype(np.float64) * ROT_STEP_RAD))
    for idx in _LEVELS:
        pred = pred_all[:, idx]
        if idx[0] == 0:
            target = world[:, idx]
        else:
            target = quat_mul(quat_conj(new_world[:, _PARENT_OF[idx]]), world[:, idx])
        u = quat2rotvec(quat_mul(quat_conj(pred), target))  # (M, n, 3)
        r = np.rint(u / ROT_STEP_RAD).astype(np.int64)
        q = normalise(quat_mul(pred, rotvec2quat(r.astype(np.float64) * ROT_STEP_RAD)))
        new_items[:, idx], r_rot[:, idx] = q, r
        new_world[:, idx] = q if idx[0] == 0 else quat_mul(new_world[:, _PARENT_OF[idx]], q)
    d_rot = step_rot + r_rot
    ref_root = np.array([r.root for r in refs], np.int64)  # (M, 3)
    d_root = np.array(roots, np.int64) - ref_root
    r_root = d_root - np.array([r.step_root for r in refs], np.int64)
    res = np.concatenate([r_root[:, None], r_rot], axis=1)  # (M, 20, 3) the residuals
    lo, hi = res.min(axis=-1), res.max(axis=-1)  # (M, 20)
    half = np.left_shift(1, np.maximum(_ITEM_WIDTHS - 1, 0))  # (20, 4)
    fits = (lo[..., None] >= -half) & (hi[..., None] < half)  # (M, 20, 4)
    fits[..., 0] = (lo == 0) & (hi == 0)
    cls = np.argmax(fits, axis=-1)  # (M, 20) the smallest class that fits
    ok = fits.any(axis=-1).all(axis=-1)  # (M,)
    dseq = (np.array(seqs, np.int64) - np.array([r.seq for r in refs], np.int64)) & UINT32_MAX
    ok &= (dseq >= 1) & (dseq <= 255)
    # Fields in stream order per item: the class (2 bits), then 3 components of its width.
    width = np.take_along_axis(
        np.broadcast_to(_ITEM_WIDTHS, (m, *_ITEM_WIDTHS.shape)), cls[..., None], -1
    )[..., 0]  # (M, 20)
    vals = np.concatenate([cls[..., None], res], axis=-1)  # (M, 20, 4)
    wids = np.concatenate(
        [np.full((m, NUM_ITEMS + 1, 1), 2), np.repeat(width[..., None], 3, -1)], axis=-1
    ).reshape(m, -1)  # (M, 80)
    total = wids.sum(axis=1)
    pad = (-total) % 8
    vals = np.concatenate([vals.reshape(m, -1), np.zeros((m, 1), np.int64)], axis=1)  # (M, 81)
    wids = np.concatenate([wids, pad[:, None]], axis=1)
    bits = (vals[..., None] >> _BIT) & 1  # (M, 81, 14), two's complement low bits
    keep = wids[..., None] > _BIT
    packed = np.packbits(bits[keep].astype(np.uint8), bitorder="little").tobytes()
    nbytes = ((total + pad) // 8).tolist()
    new_root = (d_root + ref_root).tolist()
    d_root_l = d_root.tolist()
    out: list[tuple[bytes, Recon] | None] = []
    at = 0
    for i in range(m):
        blob = packed[at : at + nbytes[i]]
        at += nbytes[i]
        if not ok[i]:
            out.append(None)
            continue
        nr, sr = new_root[i], d_root_l[i]
        recon = Recon(seqs[i], (nr[0], nr[1], nr[2]), new_items[i], (sr[0], sr[1], sr[2]), d_rot[i])
        out.append((bytes([flags[i], int(dseq[i])]) + blob, recon))
    return out
