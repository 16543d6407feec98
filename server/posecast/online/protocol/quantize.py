"""Pose quantisation for the wire: millimetre offsets and snorm16 quaternions.

Positions: the PELVIS goes as three float64 (``root``); the other 18 joints
(``Joint.SPINE`` .. ``Joint.RIGHT_TOE``) as int16 millimetres relative to it,
little-endian, 108 bytes. Rounding to the nearest millimetre bounds the error at
0.5 mm per axis (0.87 mm per joint) anywhere in the +-1000 m world, because the
offset is taken from the exact ``root`` that is sent. int16 reaches +-32.767 m from
the pelvis, far beyond any body; a wider offset is refused (OUT_OF_RANGE), never
wrapped.

Rotations: each xyzw component times 32767, rounded, int16 little-endian, 19 x 4 =
152 bytes. The component error is at most 0.5 / 32767 = 1.5e-5, the angle error
below 1e-4 rad (0.006 degrees). No sign is forced, so ``q`` and ``-q`` survive as
sent and a client's interpolation between poses sees the hemisphere the engine chose.

Decoders divide by 32767 and do not renormalise: a quantised unit quaternion is
within 3.1e-5 of unit length (invisible in a rotation matrix), and skipping it keeps
``encode(decode(b)) == b``. They still refuse a norm off 1 by more than the
quaternion tolerance (NOT_NORMALISED), which catches garbage bytes.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

from posecast.errors import NotNormalisedError, OutOfRangeError
from posecast.online.protocol.messages import MAX_COORD_M, QUAT_TOLERANCE
from posecast.skeleton import NUM_JOINTS

F64 = NDArray[np.float64]

POS_UNIT_M = 0.001  # one int16 step of a position offset
ROT_SCALE = 32767.0  # one int16 step of a quaternion component is 1 / ROT_SCALE
POS_BYTES = (NUM_JOINTS - 1) * 3 * 2  # 108
ROT_BYTES = NUM_JOINTS * 4 * 2  # 152
_I16 = np.dtype("<i2")
_I16_MAX = 32767


def roots_on_wire(positions: F64) -> F64:
    """``positions (E, 19, 3)`` with each pose moved whole, where its pelvis is past
    the wire's +-MAX_COORD_M on some axis, back to that edge: a headset-only player at
    the tracking space's edge (its head at 1000 m, allowed) facing outward gets a
    pelvis beyond it, which no client would accept. The body keeps its shape and lands
    within a pelvis-to-head offset (under a metre) of its trackers, where the world
    ends. ``positions`` itself when nothing is past the edge."""
    roots = positions[:, 0]
    inside = np.clip(roots, -MAX_COORD_M, MAX_COORD_M)
    if np.array_equal(inside, roots):  # the usual case, NaN aside (refused later)
        return positions
    shift = np.where(np.isnan(roots), 0.0, inside - roots)
    return positions + shift[:, None, :]


def pos2mm(positions: ArrayLike) -> tuple[list[float], bytes]:
    """World positions ``(19, 3)`` metres -> ``(root [3] floats, 108 offset bytes)``."""
    p = np.asarray(positions, dtype=np.float64)
    if p.shape != (NUM_JOINTS, 3):
        raise ValueError(f"positions must be ({NUM_JOINTS}, 3), got {p.shape}")
    roots, offsets = pos2mm_many(p[None])
    if offsets[0] is None:
        raise OutOfRangeError("a joint is more than 32.767 m from the pelvis", field="pos_mm")
    return roots[0], offsets[0]


def pos2mm_many(positions: F64) -> tuple[list[list[float]], list[bytes | None]]:
    """:func:`pos2mm` of ``E`` poses at once (``positions (E, 19, 3)`` float64): the
    roots, and each pose's offset bytes or ``None`` where :func:`pos2mm` refuses it."""
    roots = positions[:, 0]
    mm = np.rint((positions[:, 1:] - roots[:, None]) / POS_UNIT_M)  # (E, 18, 3)
    ok: NDArray[np.bool_] = np.all(np.abs(mm) <= _I16_MAX, axis=(1, 2))  # NaN fails too
    blob = np.where(ok[:, None, None], mm, 0.0).astype(_I16).tobytes()
    return roots.tolist(), _rows(blob, POS_BYTES, ok)


def quat2snorm_many(quats: F64) -> list[bytes | None]:
    """:func:`quat2snorm` of ``E`` poses at once (``quats (E, 19, 4)`` float64); ``None``
    where :func:`quat2snorm` refuses a pose."""
    s = np.rint(quats * ROT_SCALE)
    ok: NDArray[np.bool_] = np.all(np.abs(s) <= _I16_MAX, axis=(1, 2))  # NaN fails too
    return _rows(np.where(ok[:, None, None], s, 0.0).astype(_I16).tobytes(), ROT_BYTES, ok)


def _rows(blob: bytes, size: int, ok: NDArray[np.bool_]) -> list[bytes | None]:
    return [blob[i * size : (i + 1) * size] if good else None for i, good in enumerate(ok.tolist())]


def mm2pos(root: ArrayLike, blob: bytes) -> F64:
    """``(root [3], 108 offset bytes)`` -> world positions ``(19, 3)`` metres."""
    r = np.asarray(root, dtype=np.float64)
    out = np.empty((NUM_JOINTS, 3), dtype=np.float64)
    out[0] = r
    out[1:] = np.frombuffer(blob, dtype=_I16).reshape(NUM_JOINTS - 1, 3) * POS_UNIT_M + r
    return out


def quat2snorm(quats: ArrayLike) -> bytes:
    """Unit quaternions ``(19, 4)`` xyzw -> 152 bytes of snorm16."""
    q = np.asarray(quats, dtype=np.float64)
    if q.shape != (NUM_JOINTS, 4):
        raise ValueError(f"rotations must be ({NUM_JOINTS}, 4), got {q.shape}")
    blob = quat2snorm_many(q[None])[0]
    if blob is None:  # a component past +-1 (or NaN)
        raise NotNormalisedError("a rotation is not a unit quaternion", field="rot")
    return blob


def snorm2quat(blob: bytes) -> F64:
    """152 bytes of snorm16 -> quaternions ``(19, 4)`` xyzw (not renormalised)."""
    q: F64 = np.frombuffer(blob, dtype=_I16).reshape(NUM_JOINTS, 4) / ROT_SCALE
    n = np.sqrt(np.einsum("ij,ij->i", q, q))  # (19,)
    if not (np.abs(n - 1.0) <= QUAT_TOLERANCE).all():
        bad = int(np.argmax(np.abs(n - 1.0)))
        raise NotNormalisedError(f"rotation of joint {bad} has norm {n[bad]:.6f}", field="rot")
    return q
