"""What a v2 pose record describes (pure: numpy in, numpy and bytes out).

The items (the ``PELVIS`` world rotation, then the 18 local rotations), their
quaternion arithmetic, the skeleton and smallest-three byte layouts, and
:class:`Recon`, the state a client reconstructs from a record. The encoder is
:mod:`posecast.online.protocol.records`, the reference decoder
:mod:`posecast.online.protocol.record_decode`; the wire format is in ``proto/README.md``.

Glossary as in :mod:`posecast.geometry.rotations`: quaternions xyzw, Hamilton product.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from posecast.errors import BadFieldError, OutOfRangeError
from posecast.geometry.rotations import quat_conj, quat_mul
from posecast.online.protocol.messages import MAX_COORD_M, UINT32_MAX
from posecast.skeleton import NUM_JOINTS, PARENTS, reference_offsets

F64 = NDArray[np.float64]
I64 = NDArray[np.int64]

__all__ = [  # the record layout's public names (posecast.online.protocol.records re-exports them)
    "FLAGS_KNOWN",
    "FLAG_KEYFRAME",
    "FLAG_REACH_LIMITED",
    "KEYFRAME_BYTES",
    "MAX_AVATAR_ID",
    "MAX_DELTA_BYTES",
    "NUM_ITEMS",
    "ROOT_UNIT_M",
    "ROOT_WIDTHS",
    "ROT_STEP_RAD",
    "ROT_WIDTHS",
    "SKELETON_BYTES",
    "SKELETON_UNIT_M",
    "SMALLEST3_SCALE",
    "Recon",
    "bytes2skeleton",
    "items2world",
    "quat2rotvec",
    "rotvec2quat",
    "skeleton2bytes",
    "skeleton_offsets",
    "smallest3_pack",
    "smallest3_unpack",
    "world2items",
]

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
MAX_DELTA_BYTES = 2 + (2 + 3 * ROOT_WIDTHS[-1] + NUM_ITEMS * (2 + 3 * ROT_WIDTHS[-1]) + 7) // 8
_PARENTS = np.array(PARENTS[1:])
ROOT_MAX = round(MAX_COORD_M / ROOT_UNIT_M)


# --- quaternion helpers (float64, the exact operations the spec names; the product and the
# conjugate are posecast.geometry.rotations') ----------------------------------------------


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


def normalise(q: F64) -> F64:
    """Quaternions ``(..., 4)`` scaled to unit length."""
    n = np.sqrt(np.einsum("...i,...i->...", q, q))[..., None]
    out: F64 = q / n
    return out


def world2items(world: F64) -> F64:
    """World rotations ``(19, 4)`` -> items: PELVIS world, then each joint's local rotation."""
    items = world.copy()
    items[1:] = quat_mul(quat_conj(world[_PARENTS]), world[1:])
    return items


def items2world(items: F64) -> F64:
    """Items ``(19, 4)`` -> world rotations, parents before children."""
    world = items.copy()
    for j in range(1, NUM_JOINTS):
        world[j] = quat_mul(world[PARENTS[j]], items[j])
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
