"""Pose quantisation for the v1 ``pose`` message: millimetre offsets, snorm16 quaternions.

Positions: the ``PELVIS`` goes as three float64 (``root``); the other 18 joints as
int16 millimetres relative to it, little-endian, 108 bytes (``pos_mm``). Rotations
(``rot``): each xyzw component times 32767, rounded, int16 little-endian, 19 x 4 =
152 bytes. Decoding divides and does not renormalise (the codec refuses a norm off 1
by more than the quaternion tolerance). Pure; the server's twin is
``posecast.online.protocol.quantize``.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from posecast_client.errors import NotNormalisedError, OutOfRangeError
from posecast_client.protocol import F64, POS_UNIT_M, ROT_SCALE
from posecast_client.skeleton import NUM_JOINTS

_I16 = np.dtype("<i2")
POS_BYTES, ROT_BYTES = (NUM_JOINTS - 1) * 3 * 2, NUM_JOINTS * 4 * 2  # 108, 152


def pos2mm(positions: Any) -> tuple[list[float], bytes]:
    """Pose positions ``(19, 3)`` metres -> ``(root [3] floats, 108 bytes of int16 mm)``."""
    p = np.asarray(positions, dtype=np.float64)
    mm = np.rint((p[1:] - p[0]) / POS_UNIT_M)  # (18, 3)
    if not (np.abs(mm) <= 32767).all():
        raise OutOfRangeError("a joint is more than 32.767 m from the pelvis", field="pos_mm")
    root: list[float] = p[0].tolist()
    return root, mm.astype(_I16).tobytes()


def mm2pos(root: F64, pos_mm: bytes) -> F64:
    """``root`` ``(3,)`` metres and :data:`POS_BYTES` of int16 mm -> positions ``(19, 3)``."""
    offsets = np.frombuffer(pos_mm, _I16).reshape(NUM_JOINTS - 1, 3)
    positions = np.empty((NUM_JOINTS, 3))  # (19, 3)
    positions[0] = root
    positions[1:] = root + offsets * POS_UNIT_M
    return positions


def quat2snorm(rotations: Any) -> bytes:
    """Pose rotations ``(19, 4)`` xyzw -> 152 bytes of int16 ``round(q * 32767)``."""
    s = np.rint(np.asarray(rotations, dtype=np.float64) * ROT_SCALE)  # (19, 4)
    if not (np.abs(s) <= 32767).all():  # NaN fails too
        raise NotNormalisedError("a rotation is not a unit quaternion", field="rot")
    return s.astype(_I16).tobytes()


def snorm2quat(rot: bytes) -> F64:
    """:data:`ROT_BYTES` of int16 -> rotations ``(19, 4)`` xyzw, not renormalised."""
    quats: F64 = np.frombuffer(rot, _I16).reshape(NUM_JOINTS, 4) / ROT_SCALE  # (19, 4)
    return quats
