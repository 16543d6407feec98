"""Device formats (pure: bytes in, samples out): the serial frame and the HID report.

Both are specified in ``proto/devices.md``; this module is the reference
implementation, encoder included (for firmware tests and simulators).

Serial (a byte stream, so it needs framing)::

    A5 5A | version u8 = 1 | length u8 = 125 | payload (125 bytes) | CRC-32 u32 LE
    payload: seq u32 | t_us u64 | valid u8 | 4 x (px py pz qx qy qz qw) float32, all LE

The CRC-32 (IEEE 802.3, zlib's) covers version, length and payload. The decoder
hunts for the sync bytes, waits for ``length`` bytes and checks the CRC; on a
mismatch it drops **one** byte and hunts again, so a frame hiding behind garbage or
behind a cut-off frame is still found, and nothing unchecked is ever returned.

HID (USB delivers whole reports, with its own CRC; the CRC-8 here catches firmware
and bridge bugs)::

    report id u8 = 1 | version << 4 | valid (u8) | seq u8 | CRC-8 u8 | t_us u32 LE
    | 4 x (px py pz int16 mm, qx qy qz qw int16 x 32767), LE      = 64 bytes
"""

from __future__ import annotations

import math
import struct
import zlib
from dataclasses import dataclass, field

import numpy as np

from posecast_client.sources.base import F64, TrackerSample

SERIAL_SYNC = b"\xa5\x5a"
SERIAL_VERSION = 1
_PAYLOAD = struct.Struct("<IQB28f")  # seq, t_us, valid, 4 x 7 float32
SERIAL_PAYLOAD_BYTES = _PAYLOAD.size  # 125
SERIAL_FRAME_BYTES = 4 + SERIAL_PAYLOAD_BYTES + 4  # 133

HID_REPORT_ID = 1
HID_VERSION = 1
HID_REPORT_BYTES = 64
_HID = struct.Struct("<BBBBI28h")  # id, version|valid, seq, crc8, t_us, 4 x 7 int16
_QUAT_SLACK = 0.01  # a device quaternion this far off unit length is garbage


def _check_slots(pos: F64, quat: F64, valid: int) -> bool:
    """Tracked slots: finite, within +-1000 m, quaternion about unit length."""
    for i in range(4):
        if valid >> i & 1:
            if not (np.isfinite(pos[i]).all() and (np.abs(pos[i]) <= 1000.0).all()):
                return False
            n = math.sqrt(float(quat[i] @ quat[i]))
            if not abs(n - 1.0) <= _QUAT_SLACK:  # NaN fails too
                return False
    return True


def _untracked_to_identity(pos: F64, quat: F64, valid: int) -> None:
    for i in range(4):
        if not valid >> i & 1:
            pos[i], quat[i] = 0.0, (0.0, 0.0, 0.0, 1.0)


# --- serial ------------------------------------------------------------------------


def encode_serial_frame(
    seq: int, t_us: int, positions: F64, orientations: F64, valid: int = 0b1111
) -> bytes:
    """One serial frame (133 bytes) of a sample: ``(4, 3)`` metres, ``(4, 4)`` xyzw."""
    rows = np.hstack([positions, orientations]).astype(np.float32).ravel()  # (28,)
    payload = _PAYLOAD.pack(seq & 0xFFFFFFFF, t_us, valid, *rows.tolist())
    body = bytes((SERIAL_VERSION, len(payload))) + payload
    return SERIAL_SYNC + body + zlib.crc32(body).to_bytes(4, "little")


@dataclass
class FramingStats:
    """What a decoder has seen: good samples, and what it threw away."""

    samples: int = 0
    skipped_bytes: int = 0  # garbage before a sync, and the first byte of each bad frame
    bad_checksum: int = 0
    bad_payload: int = 0  # checksum fine but an unknown version/length or absurd values


@dataclass
class SerialFrameDecoder:
    """Incremental decoder: feed it bytes as they arrive, get complete samples back."""

    stats: FramingStats = field(default_factory=FramingStats)
    _buf: bytearray = field(default_factory=bytearray)

    def feed(self, data: bytes, now: float | None = None) -> list[TrackerSample]:
        """Bytes in, the samples they complete out (``t`` = ``now``, the host time)."""
        buf = self._buf
        buf += data
        out: list[TrackerSample] = []
        while True:
            i = buf.find(SERIAL_SYNC)
            if i < 0:  # keep a last byte that may be the first half of a sync
                keep = 1 if buf[-1:] == SERIAL_SYNC[:1] else 0
                self.stats.skipped_bytes += len(buf) - keep
                del buf[: len(buf) - keep]
                return out
            self.stats.skipped_bytes += i
            del buf[:i]
            if len(buf) < 4 or len(buf) < 8 + buf[3]:
                return out  # wait for the rest of this frame
            end = 4 + buf[3]
            if zlib.crc32(buf[2:end]) != int.from_bytes(buf[end : end + 4], "little"):
                self.stats.bad_checksum += 1
                self.stats.skipped_bytes += 1
                del buf[:1]  # not a frame: hunt again from the next byte
                continue
            sample = self._payload(bytes(buf[2:end]), now)
            del buf[: end + 4]
            if sample is None:
                self.stats.bad_payload += 1
            else:
                self.stats.samples += 1
                out.append(sample)

    @staticmethod
    def _payload(body: bytes, now: float | None) -> TrackerSample | None:
        if body[0] != SERIAL_VERSION or body[1] != SERIAL_PAYLOAD_BYTES:
            return None
        seq, t_us, valid, *values = _PAYLOAD.unpack(body[2:])
        rows = np.array(values, dtype=np.float64).reshape(4, 7)
        pos, quat = rows[:, :3].copy(), rows[:, 3:].copy()
        if valid > 0b1111 or not _check_slots(pos, quat, valid):
            return None
        _untracked_to_identity(pos, quat, valid)
        return TrackerSample(pos, quat, valid, t=now, device_seq=seq, device_t=t_us * 1e-6)


# --- HID ---------------------------------------------------------------------------


def _crc8_table() -> tuple[int, ...]:
    table = []
    for b in range(256):
        c = b
        for _ in range(8):
            c = ((c << 1) ^ 0x07) & 0xFF if c & 0x80 else (c << 1) & 0xFF
        table.append(c)
    return tuple(table)


_CRC8 = _crc8_table()


def crc8(data: bytes) -> int:
    """CRC-8/SMBUS: polynomial 0x07, initial value 0, no reflection, no final XOR."""
    c = 0
    for b in data:
        c = _CRC8[c ^ b]
    return c


def _report_crc(report: bytes) -> int:
    return crc8(report[:3] + report[4:])  # every byte but the CRC byte itself


def encode_hid_report(
    seq: int, t_us: int, positions: F64, orientations: F64, valid: int = 0b1111
) -> bytes:
    """One 64-byte HID report (report id first). Positions round to millimetres and
    must lie within +-32.767 m of the tracking origin."""
    mm = np.rint(np.asarray(positions) * 1000.0)  # (4, 3)
    sq = np.rint(np.asarray(orientations) * 32767.0)  # (4, 4)
    if not ((np.abs(mm) <= 32767).all() and (np.abs(sq) <= 32767).all()):
        raise ValueError("a position beyond +-32.767 m or a quaternion beyond unit length")
    rows = np.hstack([mm, sq]).astype(int).ravel().tolist()  # (28,)
    report = bytearray(
        _HID.pack(HID_REPORT_ID, HID_VERSION << 4 | valid, seq & 0xFF, 0, t_us & 0xFFFFFFFF, *rows)
    )
    report[3] = _report_crc(bytes(report))
    return bytes(report)


@dataclass
class HidReportDecoder:
    """Decodes reports one by one; unwraps the 8-bit seq and 32-bit microsecond clock."""

    stats: FramingStats = field(default_factory=FramingStats)
    _seq: int | None = None
    _t_us: int | None = None

    def decode(self, report: bytes, now: float | None = None) -> TrackerSample | None:
        """A report in, its sample out (``None``, counted in ``stats``, if it is bad)."""
        if len(report) != HID_REPORT_BYTES or report[0] != HID_REPORT_ID:
            self.stats.bad_payload += 1
            return None
        if report[3] != _report_crc(report):
            self.stats.bad_checksum += 1
            return None
        _, vv, seq8, _, t32, *values = _HID.unpack(report)
        rows = np.array(values, dtype=np.float64).reshape(4, 7)
        pos, quat = rows[:, :3] * 0.001, rows[:, 3:] / 32767.0
        valid = vv & 0x0F
        if vv >> 4 != HID_VERSION or not _check_slots(pos, quat, valid):
            self.stats.bad_payload += 1
            return None
        _untracked_to_identity(pos, quat, valid)
        self._seq = seq8 if self._seq is None else self._seq + ((seq8 - self._seq) & 0xFF)
        self._t_us = t32 if self._t_us is None else self._t_us + ((t32 - self._t_us) & 0xFFFFFFFF)
        self.stats.samples += 1
        return TrackerSample(
            pos, quat, valid, t=now, device_seq=self._seq, device_t=self._t_us * 1e-6
        )
