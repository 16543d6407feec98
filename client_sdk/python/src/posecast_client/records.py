"""Protocol v2 pose records, decoded (pure): ``poses.data`` bytes in, avatar states out.

Written from ``proto/README.md`` ("Pose records") apart from the server's encoder; the
stream vectors in ``proto/vectors/poses.json`` keep the two in step. A record is::

    avatar id (unsigned LEB128) | flags (u8: bit 0 keyframe, bit 1 reach_limited)
    keyframe: seq u32 LE | root 3 x i32 LE (0.1 mm) | 19 x 48-bit smallest-three
    delta:    seq step u8 (1..255) | bitstream (LSB first) of 20 items, root then the
              19 rotations: a 2-bit class, then 3 signed components of its width

Items are the ``PELVIS`` world rotation, then each joint's rotation relative to its
parent (joint order). Each item keeps its last step ``v``; a delta component ``r``
gives ``root += v + r`` (0.1 mm) and ``q = normalise((q * exp(v * STEP)) * exp(r *
STEP))`` for a rotation, then ``v = v + r``. A keyframe resets every ``v`` to 0.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from posecast_client.errors import BadFieldError
from posecast_client.skeleton import NUM_JOINTS, PARENTS

F64 = NDArray[np.float64]

ROOT_UNIT_M = 1e-4
SKELETON_UNIT_M = 1e-4
SKELETON_BYTES = 108
ROT_STEP_RAD = 2.0**-9
SMALLEST3_SCALE = 23168.0
ROT_WIDTHS = (0, 4, 7, 12)
ROOT_WIDTHS = (0, 5, 8, 14)
KEYFRAME, REACH_LIMITED = 0x01, 0x02
_ROOT_MAX = 10_000_000  # 1000 m in 0.1 mm


def skeleton2offsets(blob: bytes) -> F64:
    """A v2 skeleton (108 bytes) -> bone offsets ``(19, 3)`` metres (row 0, PELVIS, zero)."""
    out = np.zeros((NUM_JOINTS, 3))
    out[1:] = np.frombuffer(blob, "<i2").reshape(NUM_JOINTS - 1, 3) * SKELETON_UNIT_M
    return out


def _hamilton_table() -> F64:
    """``T (4, 16)`` with ``(a @ T).reshape(4, 4)[j, k]`` the ``k`` part of ``a * e_j``."""
    t = np.zeros((4, 4, 4))
    # a * b, written out for xyzw, as (i of a, j of b, k of the product, sign)
    for i, j, k, sign in (
        (3, 0, 0, 1), (0, 3, 0, 1), (1, 2, 0, 1), (2, 1, 0, -1),
        (3, 1, 1, 1), (0, 2, 1, -1), (1, 3, 1, 1), (2, 0, 1, 1),
        (3, 2, 2, 1), (0, 1, 2, 1), (1, 0, 2, -1), (2, 3, 2, 1),
        (3, 3, 3, 1), (0, 0, 3, -1), (1, 1, 3, -1), (2, 2, 3, -1),
    ):  # fmt: skip
        t[i, j, k] = sign
    return t.reshape(4, 16)


_HAMILTON = _hamilton_table()


def _mul(a: F64, b: F64) -> F64:
    """Hamilton product of xyzw quaternions ``(..., 4)`` (broadcasting): two matrix
    products, which at a message's few records cost far less than 16 elementwise ones."""
    m = (a @ _HAMILTON).reshape(*a.shape[:-1], 4, 4)  # (..., j, k): a * e_j
    out: F64 = (b[..., None, :] @ m)[..., 0, :]
    return out


def _exp(v: F64) -> F64:
    """Rotation vectors ``(..., 3)`` -> quaternions: ``(v sin(t/2) / t, cos(t/2))``."""
    t = np.sqrt((v * v).sum(axis=-1))
    moving = t > 0.0
    safe = np.where(moving, t, 1.0)
    out = np.empty((*v.shape[:-1], 4))
    out[..., :3] = v * np.where(moving, np.sin(t / 2.0) / safe, 0.0)[..., None]
    out[..., 3] = np.where(moving, np.cos(t / 2.0), 1.0)
    return out


def items2world(items: F64) -> F64:
    """Items ``(..., 19, 4)`` (PELVIS world, then local rotations) -> world rotations."""
    w = items.copy()
    for joints, parents in _LEVELS:
        w[..., joints, :] = _mul(w[..., parents, :], items[..., joints, :])
    return w


def _mat_table() -> F64:
    """``Q (16, 9)`` with ``(q q^T).reshape(16) @ Q`` the rotation matrix of unit ``q``."""
    q = np.zeros((4, 4, 3, 3))
    x, y, z, w = range(4)

    def put(r: int, c: int, terms: list[tuple[int, int, float]]) -> None:
        for i, j, v in terms:
            q[i, j, r, c] += v

    put(0, 0, [(w, w, 1), (x, x, 1), (y, y, -1), (z, z, -1)])
    put(1, 1, [(w, w, 1), (x, x, -1), (y, y, 1), (z, z, -1)])
    put(2, 2, [(w, w, 1), (x, x, -1), (y, y, -1), (z, z, 1)])
    put(0, 1, [(x, y, 2), (z, w, -2)])
    put(0, 2, [(x, z, 2), (y, w, 2)])
    put(1, 0, [(x, y, 2), (z, w, 2)])
    put(1, 2, [(y, z, 2), (x, w, -2)])
    put(2, 0, [(x, z, 2), (y, w, -2)])
    put(2, 1, [(y, z, 2), (x, w, 2)])
    return q.reshape(16, 9)


_MAT = _mat_table()


def fk(world: F64, root_m: F64, offsets: F64) -> F64:
    """Joint positions ``(..., 19, 3)`` metres from world rotations ``(..., 19, 4)``, the
    root ``(..., 3)`` and bone offsets ``(..., 19, 3)``: every bone turned by its
    parent's world rotation at once, then each joint the root plus the bones from the
    root down to it (one product with the tree's ancestor table)."""
    outer = world[..., :, None] * world[..., None, :]  # (..., 19, 4, 4)
    mats = (outer.reshape(*world.shape[:-1], 16) @ _MAT).reshape(*world.shape[:-1], 3, 3)
    off = np.broadcast_to(offsets, (*world.shape[:-1], 3))[..., 1:, :, None]  # (..., 18, 3, 1)
    bones = (mats[..., _CHILD_PARENTS, :, :] @ off)[..., 0]  # (..., 18, 3)
    pos: F64 = (_ANCESTORS @ bones) + np.asarray(root_m)[..., None, :]  # (..., 19, 3)
    return pos


def _ancestors() -> F64:
    """``A (19, 18)``: ``A[j, b - 1]`` is 1 when bone ``b`` (joint ``b``'s, from its
    parent) lies on the path from the root to joint ``j``."""
    a = np.zeros((NUM_JOINTS, NUM_JOINTS - 1))
    for j in range(1, NUM_JOINTS):
        k = j
        while k > 0:
            a[j, k - 1] = 1.0
            k = PARENTS[k]
    return a


_ANCESTORS = _ancestors()
_CHILD_PARENTS = np.array(PARENTS[1:])


def _levels() -> list[tuple[list[int], list[int]]]:
    """(joints, their parents) at each depth below the root: FK a level at a time."""
    depth = [0] * NUM_JOINTS
    for j in range(1, NUM_JOINTS):
        depth[j] = depth[PARENTS[j]] + 1
    out = []
    for d in range(1, max(depth) + 1):
        joints = [j for j in range(NUM_JOINTS) if depth[j] == d]
        out.append((joints, [PARENTS[j] for j in joints]))
    return out


_LEVELS = _levels()


@dataclass
class AvatarState:
    """What this client holds for one avatar: the last record's result."""

    seq: int
    root: list[int]  # 0.1 mm
    items: F64  # (19, 4) PELVIS world, then local rotations
    steps: NDArray[np.int64] = field(default_factory=lambda: np.zeros((20, 3), np.int64))

    def world(self) -> F64:
        """World rotations ``(19, 4)`` from the items."""
        return items2world(self.items)

    def positions(self, offsets: F64) -> F64:
        """Joint positions ``(19, 3)`` metres: FK with bone ``offsets (19, 3)``."""
        return fk(self.world(), np.array(self.root, dtype=np.float64) * ROOT_UNIT_M, offsets)


@dataclass(frozen=True)
class DecodedRecord:
    avatar_id: int
    keyframe: bool
    reach_limited: bool
    state: AvatarState


_MAX_DELTA_BYTES = 110  # 20 items of the widest class: (2 + 3 * 14 + 19 * (2 + 3 * 12)) bits


def _leb128(data: bytes, pos: int) -> tuple[int, int]:
    value = 0
    for k in range(5):
        if pos + k >= len(data):
            raise BadFieldError("a record is cut short in its avatar id", field="data")
        b = data[pos + k]
        value |= (b & 0x7F) << (7 * k)
        if not b & 0x80:
            if k and b == 0:
                raise BadFieldError("an avatar id that is not minimal LEB128", field="data")
            if value > 0xFFFFFFFF:
                raise BadFieldError("an avatar id over 2**32 - 1", field="data")
            return value, pos + k + 1
    raise BadFieldError("an avatar id of more than 5 bytes", field="data")


def _smallest3(word: int) -> list[float]:
    if word >> 47:
        raise BadFieldError("bit 47 of a keyframe rotation is set", field="data")
    rest: list[float] = []
    for n in range(3):
        bits = word >> (15 * n) & 0x7FFF
        rest.append((bits - 0x8000 if bits >= 0x4000 else bits) / SMALLEST3_SCALE)
    a, b, c = rest
    rest.insert(word >> 45 & 3, math.sqrt(max(0.0, 1.0 - (a * a + b * b + c * c))))
    return rest


def decode_records(data: bytes, avatars: dict[int, AvatarState | None]) -> list[DecodedRecord]:
    """Every record of ``data``, each applied to ``avatars`` (avatar id -> state, ``None``
    for an announced avatar without a keyframe yet), which it updates.

    Raises:
        BadFieldError: (field ``data``) a record is cut short, has reserved bits set,
            names an avatar id not in ``avatars``, or is a delta with nothing to apply to.
    """
    out: list[DecodedRecord] = []
    pending: list[tuple[int, int, AvatarState, NDArray[np.int64], list[list[int]], int]] = []

    def flush() -> None:
        # Every delta waiting, its rotations in one batch: (n, 19, 4).
        if not pending:
            return
        prev = np.stack([p[2].items for p in pending])
        v = np.stack([p[2].steps[1:] for p in pending]).astype(np.float64) * ROT_STEP_RAD
        r = np.array([p[4][1:] for p in pending], dtype=np.float64) * ROT_STEP_RAD
        q = _mul(_mul(prev, _exp(v)), _exp(r))
        q /= np.sqrt((q * q).sum(axis=-1))[..., None]
        for k, (i, avatar_id, last, steps, _, seq) in enumerate(pending):
            root = [last.root[c] + int(steps[0, c]) for c in range(3)]
            state = AvatarState(seq, root, q[k], steps)
            avatars[avatar_id] = state
            rec = out[i]
            out[i] = DecodedRecord(rec.avatar_id, rec.keyframe, rec.reach_limited, state)
        pending.clear()

    pos = 0
    while pos < len(data):
        avatar_id, pos = _leb128(data, pos)
        if avatar_id not in avatars:
            raise BadFieldError(f"avatar id {avatar_id} was never announced", field="data")
        if pos >= len(data):
            raise BadFieldError("a record ends after its avatar id", field="data")
        flags = data[pos]
        pos += 1
        if flags & ~(KEYFRAME | REACH_LIMITED):
            raise BadFieldError(f"reserved record flags {flags:#04x}", field="data")
        if flags & KEYFRAME:
            if pos + 130 > len(data):
                raise BadFieldError("a keyframe record is cut short", field="data")
            seq = int.from_bytes(data[pos : pos + 4], "little")
            root = [int.from_bytes(data[pos + 4 + 4 * i : pos + 8 + 4 * i], "little", signed=True)
                    for i in range(3)]  # fmt: skip
            if max(abs(v) for v in root) > _ROOT_MAX:
                raise BadFieldError("a keyframe root beyond 1000 m", field="data")
            rot = [_smallest3(int.from_bytes(data[pos + 16 + 6 * i : pos + 22 + 6 * i], "little"))
                   for i in range(NUM_JOINTS)]  # fmt: skip
            state = AvatarState(seq, root, np.array(rot))
            pos += 130
        else:
            if any(p[1] == avatar_id for p in pending):
                flush()  # the same avatar twice in one message: apply the first one first
            prev = avatars[avatar_id]
            if prev is None:
                raise BadFieldError(f"a delta for avatar id {avatar_id} before its keyframe",
                                    field="data")  # fmt: skip
            seq, steps, residuals, pos = _delta(data, pos, prev)
            pending.append((len(out), avatar_id, prev, steps, residuals, seq))
            out.append(DecodedRecord(avatar_id, False, bool(flags & REACH_LIMITED), prev))
            continue
        avatars[avatar_id] = state
        out.append(DecodedRecord(avatar_id, bool(flags & KEYFRAME), bool(flags & REACH_LIMITED),
                                 state))  # fmt: skip
    flush()
    return out


_CLASS_WIDTHS = [ROOT_WIDTHS] + [ROT_WIDTHS] * NUM_JOINTS  # per item, by class


def _delta(
    data: bytes, pos: int, prev: AvatarState
) -> tuple[int, NDArray[np.int64], list[list[int]], int]:
    """One delta's seq, new steps ``(20, 3)``, residuals (20 x 3 ints) and its end."""
    if pos >= len(data) or data[pos] == 0:
        raise BadFieldError("a delta's seq step is missing or zero", field="data")
    seq = (prev.seq + data[pos]) & 0xFFFFFFFF
    start = pos + 1
    chunk = data[start : start + _MAX_DELTA_BYTES]
    acc, avail, bit = int.from_bytes(chunk, "little"), 8 * len(chunk), 0
    residuals = []
    for widths in _CLASS_WIDTHS:
        w = widths[acc >> bit & 3]
        bit += 2
        if not w:
            residuals.append([0, 0, 0])
            continue
        mask, half = (1 << w) - 1, 1 << (w - 1)
        v = acc >> bit
        c0, c1, c2 = v & mask, v >> w & mask, v >> 2 * w & mask
        residuals.append([c0 - (c0 & half) * 2, c1 - (c1 & half) * 2, c2 - (c2 & half) * 2])
        bit += 3 * w
    if bit > avail:
        raise BadFieldError("a delta record is cut short", field="data")
    steps = prev.steps + np.array(residuals, dtype=np.int64)  # (20, 3)
    root = [prev.root[i] + int(steps[0, i]) for i in range(3)]
    if max(abs(v) for v in root) > _ROOT_MAX:
        raise BadFieldError("a delta takes the root beyond 1000 m", field="data")
    return seq, steps, residuals, start + ((bit + 7) >> 3)
