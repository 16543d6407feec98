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

Glossary as in :mod:`posecast.geometry.rotations`: quaternions xyzw, Hamilton product.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from types import ModuleType
from typing import Any

import numpy as np
from numpy.typing import NDArray

from posecast.errors import BadFieldError, OutOfRangeError
from posecast.online.protocol.messages import MAX_COORD_M, UINT32_MAX
from posecast.skeleton import NUM_JOINTS, PARENTS, reference_offsets

_native: ModuleType | None
try:  # the C encoder of deltas (optional, as the native engine backend is)
    from posecast import _native
except ImportError:  # pragma: no cover - an install without a C compiler
    _native = None

F64 = NDArray[np.float64]
I64 = NDArray[np.int64]

NUM_ITEMS = NUM_JOINTS  # 19 rotation items: PELVIS world, then 18 local rotations
ROOT_UNIT_M = 1e-4  # one step of the root position (0.1 mm)
SKELETON_UNIT_M = 1e-4  # one step of a skeleton bone offset (0.1 mm)
SKELETON_BYTES = (NUM_JOINTS - 1) * 3 * 2  # 108: 18 x 3 int16
SMALLEST3_SCALE = 23168.0  # a smallest-three component is int15 / 23168 (|c| <= 1/sqrt 2)
ROT_STEP_RAD = 2.0**-9  # one step of a delta's rotation vector (0.112 deg)
ROT_WIDTHS = (0, 4, 7, 12)  # bits per component of a rotation residual, by class
ROOT_WIDTHS = (0, 5, 8, 14)  # bits per component of a root residual (0.1 mm), by class
FLAG_KEYFRAME = 0x01
FLAG_REACH_LIMITED = 0x02
FLAGS_KNOWN = FLAG_KEYFRAME | FLAG_REACH_LIMITED
KEYFRAME_BYTES = 1 + 4 + 12 + NUM_ITEMS * 6  # flags .. rotations: 131 (plus the avatar id)
MAX_AVATAR_ID = UINT32_MAX
_MAX_DELTA_BYTES = 2 + (2 + 3 * ROOT_WIDTHS[-1] + NUM_ITEMS * (2 + 3 * ROT_WIDTHS[-1]) + 7) // 8
_PARENTS = np.array(PARENTS[1:])
_ROOT_MAX = round(MAX_COORD_M / ROOT_UNIT_M)


# --- quaternion helpers (float64, the exact operations the spec names) -------------------


def _qmul(a: F64, b: F64) -> F64:
    """Hamilton product of xyzw quaternions, ``(..., 4)``."""
    ax, ay, az, aw = a[..., 0], a[..., 1], a[..., 2], a[..., 3]
    bx, by, bz, bw = b[..., 0], b[..., 1], b[..., 2], b[..., 3]
    return np.stack(
        [
            aw * bx + ax * bw + ay * bz - az * by,
            aw * by - ax * bz + ay * bw + az * bx,
            aw * bz + ax * by - ay * bx + az * bw,
            aw * bw - ax * bx - ay * by - az * bz,
        ],
        axis=-1,
    )


def _conj(q: F64) -> F64:
    out = q.copy()
    out[..., :3] *= -1.0
    return out


def quat2rotvec(q: F64) -> F64:
    """Unit quaternions ``(..., 4)`` -> rotation vectors ``(..., 3)`` (the shorter way)."""
    q = np.where(q[..., 3:4] < 0.0, -q, q)
    v = q[..., :3]
    s = np.sqrt(np.einsum("...i,...i->...", v, v))[..., None]
    theta = 2.0 * np.arctan2(s, q[..., 3:4])
    out: F64 = np.where(s > 0.0, v * (theta / np.where(s > 0.0, s, 1.0)), 0.0)
    return out


def rotvec2quat(v: F64) -> F64:
    """Rotation vectors ``(..., 3)`` -> unit quaternions: ``(v sin(t/2)/t, cos(t/2))``."""
    theta = np.sqrt(np.einsum("...i,...i->...", v, v))[..., None]
    safe = np.where(theta > 0.0, theta, 1.0)
    k = np.where(theta > 0.0, np.sin(theta / 2.0) / safe, 0.0)
    return np.concatenate([v * k, np.where(theta > 0.0, np.cos(theta / 2.0), 1.0)], axis=-1)


def _normalise(q: F64) -> F64:
    n = np.sqrt(np.einsum("...i,...i->...", q, q))[..., None]
    out: F64 = q / n
    return out


def world2items(world: F64) -> F64:
    """World rotations ``(19, 4)`` -> items: PELVIS world, then each joint's local rotation."""
    items = world.copy()
    items[1:] = _qmul(_conj(world[_PARENTS]), world[1:])
    return items


def items2world(items: F64) -> F64:
    """Items ``(19, 4)`` -> world rotations, parents before children."""
    world = items.copy()
    for j in range(1, NUM_JOINTS):
        world[j] = _qmul(world[PARENTS[j]], items[j])
    return world


# --- skeletons ---------------------------------------------------------------------------


def skeleton_offsets(scale: float) -> F64:
    """The bone offsets ``(18, 3)`` metres of a player calibrated to ``scale``
    (canonical metres per user metre): the reference body's divided by it."""
    return reference_offsets()[1:] / scale


def skeleton2bytes(offsets: F64) -> bytes:
    """Bone offsets ``(18, 3)`` metres -> 108 bytes of int16 LE in 0.1 mm."""
    a = np.rint(np.asarray(offsets, dtype=np.float64) / SKELETON_UNIT_M)
    if a.shape != (NUM_JOINTS - 1, 3) or not (np.abs(a) <= 32767).all():
        raise OutOfRangeError("a bone offset is beyond 3.2767 m", field="skeleton")
    return a.astype("<i2").tobytes()


def bytes2skeleton(blob: bytes) -> F64:
    """108 bytes -> bone offsets ``(18, 3)`` metres."""
    out: F64 = np.frombuffer(blob, "<i2").reshape(NUM_JOINTS - 1, 3) * SKELETON_UNIT_M
    return out


# --- smallest-three ------------------------------------------------------------------------


def smallest3_pack(q: F64) -> bytes:
    """Quaternions ``(n, 4)`` -> n x 6 bytes.

    Each 48-bit little-endian word holds, from bit 0: three 15-bit two's-complement
    components (the quaternion without its largest-magnitude one, in xyzw order,
    times 23168, rounded half to even), the 2-bit index of the dropped component at
    bits 45-46, and a zero bit 47. The quaternion's sign is chosen so the dropped one
    is positive.
    """
    n = len(q)
    idx = np.argmax(np.abs(q), axis=-1)  # (n,) the first largest on ties
    sign = np.where(np.take_along_axis(q, idx[:, None], -1) < 0.0, -1.0, 1.0)
    rest = (q * sign)[idx[:, None] != _COMPONENTS].reshape(n, 3)
    c = np.rint(rest * SMALLEST3_SCALE).astype(np.int64) & 0x7FFF
    word = idx.astype(np.int64) << 45 | c[:, 0] | c[:, 1] << 15 | c[:, 2] << 30
    out: bytes = word.astype("<u8").view(np.uint8).reshape(n, 8)[:, :6].tobytes()
    return out


def smallest3_unpack(blob: bytes) -> F64:
    """n x 6 bytes -> quaternions ``(n, 4)``: the dropped component is
    ``sqrt(max(0, 1 - (a*a + b*b + c*c)))``; BAD_FIELD for a set bit 47."""
    n = len(blob) // 6
    raw = np.zeros((n, 8), np.uint8)
    raw[:, :6] = np.frombuffer(blob, np.uint8, 6 * n).reshape(n, 6)
    word = raw.view("<u8")[:, 0].astype(np.int64)
    if (word >> 47).any():
        raise BadFieldError("a keyframe rotation has its reserved bit set", field="data")
    bits = word[:, None] >> _SHIFTS & 0x7FFF  # (n, 3)
    comps = np.where(bits & 0x4000, bits - 0x8000, bits) / SMALLEST3_SCALE
    a, b, c = comps[:, 0], comps[:, 1], comps[:, 2]
    big = np.sqrt(np.maximum(0.0, 1.0 - (a * a + b * b + c * c)))
    dropped = (word >> 45 & 3)[:, None] == _COMPONENTS  # (n, 4)
    q = np.empty((n, 4))
    q[dropped] = big
    q[~dropped] = comps.reshape(-1)
    return q


_COMPONENTS = np.arange(4)
_SHIFTS = np.array([0, 15, 30], np.int64)


# --- the state a client reconstructs ------------------------------------------------------


@dataclass(frozen=True, eq=False)
class Recon:
    """What a client holds for one avatar after a record: never mutated, so clients
    whose references are the same object can share one encoding of the next pose."""

    seq: int
    root: tuple[int, int, int]  # 0.1 mm
    items: F64  # (19, 4) reconstructed items
    step_root: tuple[int, int, int] = (0, 0, 0)  # the last step d of each item
    step_rot: I64 = field(default_factory=lambda: np.zeros((NUM_ITEMS, 3), np.int64))

    def positions(self, offsets: F64) -> F64:
        """Joint positions ``(19, 3)`` metres by FK with bone ``offsets (18, 3)``."""
        world = items2world(self.items)
        mats = _quat2mat(world)
        out = np.empty((NUM_JOINTS, 3))
        out[0] = np.asarray(self.root, dtype=np.float64) * ROOT_UNIT_M
        for j in range(1, NUM_JOINTS):
            p = PARENTS[j]
            out[j] = out[p] + mats[p] @ offsets[j - 1]
        return out


def _quat2mat(q: F64) -> F64:
    x, y, z, w = q[..., 0], q[..., 1], q[..., 2], q[..., 3]
    return np.stack(
        [
            1 - 2 * (y * y + z * z),
            2 * (x * y - z * w),
            2 * (x * z + y * w),
            2 * (x * y + z * w),
            1 - 2 * (x * x + z * z),
            2 * (y * z - x * w),
            2 * (x * z - y * w),
            2 * (y * z + x * w),
            1 - 2 * (x * x + y * y),
        ],
        axis=-1,
    ).reshape(*q.shape[:-1], 3, 3)


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
        if not (np.abs(root) <= _ROOT_MAX).all():
            raise OutOfRangeError("the pelvis is beyond +-1000 m", field="root")
        r = root.astype(np.int64).tolist()
        w = _normalise(q)
        return cls(player, seq, t, (r[0], r[1], r[2]), world2items(w), w, scale, reach_limited)

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
        q = _normalise(np.asarray(rotations, dtype=np.float64))  # (E, 19, 4)
        items = q.copy()
        items[:, 1:] = _qmul(_conj(q[:, _PARENTS]), q[:, 1:])
        root = np.rint(np.asarray(positions, dtype=np.float64)[:, 0] / ROOT_UNIT_M)  # (E, 3)
        inside: NDArray[np.bool_] = np.all(np.abs(root) <= _ROOT_MAX, axis=1)
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
    body = np.empty((m, _MAX_DELTA_BYTES), np.uint8)
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
        at = i * _MAX_DELTA_BYTES
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
    pred_all = _qmul(ref_items, rotvec2quat(step_rot.astype(np.float64) * ROT_STEP_RAD))
    for idx in _LEVELS:
        pred = pred_all[:, idx]
        if idx[0] == 0:
            target = world[:, idx]
        else:
            target = _qmul(_conj(new_world[:, _PARENT_OF[idx]]), world[:, idx])
        u = quat2rotvec(_qmul(_conj(pred), target))  # (M, n, 3)
        r = np.rint(u / ROT_STEP_RAD).astype(np.int64)
        q = _normalise(_qmul(pred, rotvec2quat(r.astype(np.float64) * ROT_STEP_RAD)))
        new_items[:, idx], r_rot[:, idx] = q, r
        new_world[:, idx] = q if idx[0] == 0 else _qmul(new_world[:, _PARENT_OF[idx]], q)
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


# --- decoding (the server's reference decoder: tests and the vector generator) -------------


@dataclass(frozen=True)
class Record:
    """One decoded record: whose (``avatar_id``), which frame, and the new state."""

    avatar_id: int
    keyframe: bool
    reach_limited: bool
    recon: Recon


def read_leb128(data: bytes, pos: int) -> tuple[int, int]:
    """An unsigned LEB128 at ``pos`` (at most 5 bytes, <= 2**32 - 1) -> (value, next pos)."""
    value = shift = 0
    for k in range(5):
        if pos + k >= len(data):
            raise BadFieldError("a record is cut short in its avatar id", field="data")
        b = data[pos + k]
        value |= (b & 0x7F) << shift
        shift += 7
        if not b & 0x80:
            if value > MAX_AVATAR_ID or (k and b == 0):
                raise BadFieldError("an avatar id is too large or not minimal", field="data")
            return value, pos + k + 1
    raise BadFieldError("an avatar id is longer than 5 bytes", field="data")


def write_leb128(value: int) -> bytes:
    out = bytearray()
    while True:
        b = value & 0x7F
        value >>= 7
        out.append(b | (0x80 if value else 0))
        if not value:
            return bytes(out)


def decode_records(data: bytes, refs: dict[int, Recon | None]) -> list[Record]:
    """Every record of a ``poses.data`` blob, against the references ``refs`` (avatar id ->
    the last state, ``None`` for an announced avatar without one yet). Updates
    ``refs``. BAD_FIELD (field ``data``) for a malformed record, an unknown avatar id or a
    delta without a reference."""
    out: list[Record] = []
    pos = 0
    while pos < len(data):
        avatar_id, pos = read_leb128(data, pos)
        if avatar_id not in refs:
            raise BadFieldError(
                f"a record for avatar id {avatar_id}, never announced", field="data"
            )
        if pos >= len(data):
            raise BadFieldError("a record is cut short", field="data")
        flags = data[pos]
        if flags & ~FLAGS_KNOWN:
            raise BadFieldError("a record has reserved flag bits set", field="data")
        if flags & FLAG_KEYFRAME:
            body = data[pos + 1 : pos + KEYFRAME_BYTES]
            if len(body) != KEYFRAME_BYTES - 1:
                raise BadFieldError("a keyframe is cut short", field="data")
            seq = int.from_bytes(body[:4], "little")
            root = tuple(
                int.from_bytes(body[4 + 4 * i : 8 + 4 * i], "little", signed=True) for i in range(3)
            )
            if max(map(abs, root)) > _ROOT_MAX:
                raise BadFieldError("a keyframe root is beyond +-1000 m", field="data")
            recon = Recon(seq, root, smallest3_unpack(body[16:]))  # type: ignore[arg-type]
            pos += KEYFRAME_BYTES
        else:
            ref = refs[avatar_id]
            if ref is None:
                raise BadFieldError(
                    f"a delta for avatar id {avatar_id} without a keyframe", field="data"
                )
            recon, pos = _read_delta(data, pos + 1, ref)
        refs[avatar_id] = recon
        out.append(
            Record(avatar_id, bool(flags & FLAG_KEYFRAME), bool(flags & FLAG_REACH_LIMITED), recon)
        )
    return out


def _read_delta(data: bytes, pos: int, ref: Recon) -> tuple[Recon, int]:
    if pos >= len(data) or not 1 <= data[pos] <= 255:
        raise BadFieldError("a delta's seq step is missing or 0", field="data")
    seq = (ref.seq + data[pos]) & UINT32_MAX
    pos += 1
    acc = int.from_bytes(data[pos : pos + _MAX_DELTA_BYTES], "little")
    avail = 8 * min(_MAX_DELTA_BYTES, len(data) - pos)
    n = 0
    steps: list[list[int]] = []
    for item in range(1 + NUM_ITEMS):
        widths = ROOT_WIDTHS if item == 0 else ROT_WIDTHS
        c = acc >> n & 3
        n += 2
        w = widths[c]
        comps = []
        for _ in range(3):
            v = acc >> n & ((1 << w) - 1) if w else 0
            comps.append(v - (1 << w) if w and v >> (w - 1) else v)
            n += w
        steps.append(comps)
    if n > avail:
        raise BadFieldError("a delta is cut short", field="data")
    pos += (n + 7) // 8
    d_root = [ref.step_root[i] + steps[0][i] for i in range(3)]
    r_rot = np.array(steps[1:], dtype=np.int64)
    d_rot = ref.step_rot + r_rot
    root = (ref.root[0] + d_root[0], ref.root[1] + d_root[1], ref.root[2] + d_root[2])
    if max(map(abs, root)) > _ROOT_MAX:
        raise BadFieldError("a delta takes the root beyond +-1000 m", field="data")
    pred = _qmul(ref.items, rotvec2quat(ref.step_rot.astype(np.float64) * ROT_STEP_RAD))
    items = _normalise(_qmul(pred, rotvec2quat(r_rot.astype(np.float64) * ROT_STEP_RAD)))
    return Recon(seq, root, items, (d_root[0], d_root[1], d_root[2]), d_rot), pos
