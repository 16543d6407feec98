"""The server's reference decoder of v2 pose records (pure: bytes in, states out).

Used by the tests and the vector generator; the record layout is in
:mod:`posecast.online.protocol.records` and ``proto/README.md``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from posecast.errors import BadFieldError
from posecast.geometry.rotations import quat_mul
from posecast.online.protocol.messages import UINT32_MAX
from posecast.online.protocol.record_state import (
    FLAG_KEYFRAME,
    FLAG_REACH_LIMITED,
    FLAGS_KNOWN,
    KEYFRAME_BYTES,
    MAX_AVATAR_ID,
    MAX_DELTA_BYTES,
    NUM_ITEMS,
    ROOT_MAX,
    ROOT_WIDTHS,
    ROT_STEP_RAD,
    ROT_WIDTHS,
    Recon,
    normalise,
    rotvec2quat,
    smallest3_unpack,
)

__all__ = ["Record", "decode_records", "read_leb128", "write_leb128"]


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
            if max(map(abs, root)) > ROOT_MAX:
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
    acc = int.from_bytes(data[pos : pos + MAX_DELTA_BYTES], "little")
    avail = 8 * min(MAX_DELTA_BYTES, len(data) - pos)
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
    if max(map(abs, root)) > ROOT_MAX:
        raise BadFieldError("a delta takes the root beyond +-1000 m", field="data")
    pred = quat_mul(ref.items, rotvec2quat(ref.step_rot.astype(np.float64) * ROT_STEP_RAD))
    items = normalise(quat_mul(pred, rotvec2quat(r_rot.astype(np.float64) * ROT_STEP_RAD)))
    return Recon(seq, root, items, (d_root[0], d_root[1], d_root[2]), d_rot), pos
