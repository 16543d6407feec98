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

Version 2 of both carries the rows of a **tracker set** (any of the ten sites, each
positional or inertial), each row naming its site::

    serial payload: seq u32 | t_us u64 | valid u16 | n u8 | n x row       (15 + 21 n)
        row: site u8 (bits 0-3 the site, bit 7 inertial) | x y z float32 (m or m/s^2)
             | qx qy qz qw int16 x 32767
    HID report id 2 (161 bytes): id | 2 << 4 | seq u8 | CRC-8 | t_us u32 | valid u16
        | n u8 | 10 x row (site u8 | x y z int16: mm, or cm/s^2 inertial | q int16 x 4)
"""

from __future__ import annotations

import dataclasses
import math
import struct
import zlib
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from posecast_client.sites import INERTIAL_SUFFIX, SITES, TrackerSet
from posecast_client.sources.base import F64, TrackerSample

SERIAL_SYNC = b"\xa5\x5a"
SERIAL_VERSION = 1
_PAYLOAD = struct.Struct("<IQB28f")  # seq, t_us, valid, 4 x 7 float32
_SERIAL_COUNTERS = struct.Struct("<IQ")  # seq, t_us: how both versions' payloads start
SERIAL_PAYLOAD_BYTES = _PAYLOAD.size  # 125
SERIAL_FRAME_BYTES = 4 + SERIAL_PAYLOAD_BYTES + 4  # 133

HID_REPORT_ID = 1
HID_VERSION = 1
HID_REPORT_BYTES = 64
_HID = struct.Struct("<BBBBI28h")  # id, version|valid, seq, crc8, t_us, 4 x 7 int16
_QUAT_SLACK = 0.01  # a device quaternion this far off unit length is garbage

# Version 2: a tracker set's rows (proto/devices.md, "Tracker sets").
SITES_VERSION = 2
_SITES_HEAD = struct.Struct("<IQHB")  # seq, t_us, valid, n
_SITES_ROW = struct.Struct("<B3f4h")  # site | inertial << 7, x y z, quaternion x 32767
MAX_DEVICE_SITES = len(SITES)  # 10
HID_SITES_REPORT_ID = 2
_HID_SITES_HEAD = struct.Struct("<BBBBIHB")  # id, version << 4, seq, crc8, t_us, valid, n
_HID_SITES_ROW = struct.Struct("<B3h4h")  # site | inertial << 7, x y z, quaternion x 32767
HID_SITES_REPORT_BYTES = _HID_SITES_HEAD.size + MAX_DEVICE_SITES * _HID_SITES_ROW.size  # 161
INERTIAL_BIT = 0x80
ACC_UNIT = 0.01  # m/s^2 per int16 step of a HID inertial row


def _check_slots(pos: F64, quat: F64, valid: int) -> bool:
    """Tracked rows (the four slots, or a set's sites): finite, within +-1000, quaternion
    about unit length."""
    for i in range(len(pos)):
        if valid >> i & 1:
            if not (np.isfinite(pos[i]).all() and (np.abs(pos[i]) <= 1000.0).all()):
                return False
            n = math.sqrt(float(quat[i] @ quat[i]))
            if not abs(n - 1.0) <= _QUAT_SLACK:  # NaN fails too
                return False
    return True


def _untracked_to_identity(pos: F64, quat: F64, valid: int) -> None:
    for i in range(len(pos)):
        if not valid >> i & 1:
            pos[i], quat[i] = 0.0, (0.0, 0.0, 0.0, 1.0)


def _site_names(codes: list[int]) -> tuple[str, ...] | None:
    """Row codes (site | inertial << 7) -> ``("head", "left_foot:imu", ...)``, or None
    for an unknown site, a reserved bit or a site listed twice."""
    names = []
    for c in codes:
        site = c & 0x7F
        if site >= MAX_DEVICE_SITES:
            return None
        names.append(SITES[site] + (INERTIAL_SUFFIX if c & INERTIAL_BIT else ""))
    bare = [n.split(":")[0] for n in names]
    return tuple(names) if len(set(bare)) == len(bare) else None


def _site_codes(sites: tuple[str, ...] | list[str]) -> list[int]:
    codes = []
    for name in sites:
        imu = name.endswith(INERTIAL_SUFFIX)
        codes.append(
            SITES.index(name[: -len(INERTIAL_SUFFIX)] if imu else name)
            | (INERTIAL_BIT if imu else 0)
        )
    return codes


def to_tracker_set(sample: TrackerSample, tracker_set: TrackerSet) -> TrackerSample:
    """A tracker-set device's sample in the rows of ``tracker_set``: each site of the set
    from the device row that names it (same kind), untracked where the device has
    none; rows the set does not list are dropped."""
    n = len(tracker_set)
    pos = np.zeros((n, 3))
    quat = np.tile([0.0, 0.0, 0.0, 1.0], (n, 1))
    valid = 0
    rows = {name: j for j, name in enumerate(sample.sites or ())}
    for i, (site, imu) in enumerate(zip(tracker_set.sites, tracker_set.inertial, strict=True)):
        j = rows.get(site + (INERTIAL_SUFFIX if imu else ""))
        if j is not None and sample.valid >> j & 1:
            pos[i], quat[i] = sample.positions[j], sample.orientations[j]
            valid |= 1 << i
    return TrackerSample(
        pos, quat, valid, t=sample.t, device_seq=sample.device_seq, device_t=sample.device_t,
        sites=tuple(tracker_set.name.split(",")),
    )  # fmt: skip


# --- serial ------------------------------------------------------------------------


def encode_serial_frame(
    seq: int, t_us: int, positions: F64, orientations: F64, valid: int = 0b1111
) -> bytes:
    """One serial frame (133 bytes) of a sample: ``(4, 3)`` metres, ``(4, 4)`` xyzw."""
    rows = np.hstack([positions, orientations]).astype(np.float32).ravel()  # (28,)
    payload = _PAYLOAD.pack(seq & 0xFFFFFFFF, t_us, valid, *rows.tolist())
    body = bytes((SERIAL_VERSION, len(payload))) + payload
    return SERIAL_SYNC + body + zlib.crc32(body).to_bytes(4, "little")


def encode_serial_sites(
    seq: int,
    t_us: int,
    sites: tuple[str, ...] | list[str],
    values: F64,
    orientations: F64,
    valid: int | None = None,
) -> bytes:
    """One version-2 serial frame of a tracker set's rows: ``sites`` names each row
    (``left_foot:imu`` for an inertial one), ``values`` ``(n, 3)`` metres or m/s^2,
    ``orientations`` ``(n, 4)`` xyzw."""
    n = len(sites)
    if not 1 <= n <= MAX_DEVICE_SITES:
        raise ValueError(f"1 to {MAX_DEVICE_SITES} rows, not {n}")
    mask = (1 << n) - 1 if valid is None else valid
    q = np.rint(np.asarray(orientations, dtype=np.float64) * 32767.0).astype(int)
    payload = _SITES_HEAD.pack(seq & 0xFFFFFFFF, t_us, mask, n) + b"".join(
        _SITES_ROW.pack(code, *map(float, v), *map(int, qq))
        for code, v, qq in zip(_site_codes(sites), np.asarray(values), q, strict=True)
    )
    body = bytes((SITES_VERSION, len(payload))) + payload
    return SERIAL_SYNC + body + zlib.crc32(body).to_bytes(4, "little")


@dataclass
class FramingStats:
    """What a decoder has seen: good samples, and what it threw away."""

    samples: int = 0
    skipped_bytes: int = 0  # garbage before a sync, and the first byte of each bad frame
    bad_checksum: int = 0
    bad_payload: int = 0  # checksum fine but an unknown version/length or absurd values
    disconnects: int = 0  # the device failed (unplugged, reset): reopened when back
    device_resets: int = 0  # the device's counters started over, its port or handle open


RESET_SLACK_S = 1.0  # how far a sample's t_us may run ahead of the host's clock
CLOCK_DRIFT = 1e-3  # how fast (s per host s) the smallest host - device offset may rise
_SEQ_TRUSTED_BITS = 16  # a seq this wide is checked against the time step (serial: 32)


@dataclass
class DeviceCounters:
    """A device's frame counter ``seq`` and microsecond clock ``t_us``, sent wrapping at
    ``seq_bits`` and ``t_bits`` (HID: 8 and 32; serial: 32 and 64), carried on into
    ever-increasing values.

    The host times each sample with ``now``; the device's clock is judged against the
    host's in absolute terms. The smallest host - device offset seen (``now`` minus the
    unwrapped ``t_us``: the device's epoch plus the least latency) says the latest time
    a sample can claim: a sample that waited in a queue claims an earlier one, never a
    later one. A sample whose ``t_us`` (read as a wrap) claims a time more than
    :data:`RESET_SLACK_S` later than ``now`` minus that offset is no wrap but a device
    reset with the port or handle still open (read as a wrap, a HID clock would run up
    to 71.6 minutes ahead; a serial one, never wrapping, would step back). The smallest
    offset may rise by :data:`CLOCK_DRIFT` per second, for a device clock slower than
    the host's. So a host that stalled (hidraw keeps 64 reports, a tty buffer a few
    thousand bytes, and both drop the newest when full) reads the queued samples and
    then a fresh one whose clock moved by the whole stall: no reset. With a seq of 16
    bits or more (serial), a sample ahead whose seq step matches its time step (at the
    device's period, as the last steps gave it) is no reset either: a stale first
    sample, read from a buffer filled before the port was opened, sets the offset too
    high. On a reset both counters carry on from where they were (``t_us`` by the
    host's elapsed time, ``seq`` by one), counted in ``stats.device_resets``. Without
    host times, only a ``t_us`` behind (by less than half the wrap) is a reset, and the
    clock carries on by the last step.
    """

    seq_bits: int
    t_bits: int
    _seq: int | None = None  # unwrapped, as the last sample gave them
    _t_us: int | None = None
    _raw: tuple[int, int] = (0, 0)  # the last sample's seq and t_us as sent
    _now: float | None = None  # the host's time of the last sample
    _step_us: int = 0  # the last step of t_us between samples (not a reset)
    _period_us: float | None = None  # t_us per seq step, as the last such step gave it
    _min_off: float | None = None  # the smallest host - device offset (s), as of _min_at
    _min_at: float = 0.0

    def reset(self) -> None:
        """Forget the counters: a device that came back starts them anew."""
        self._seq = self._t_us = self._now = self._period_us = self._min_off = None
        self._step_us = 0

    def _floor(self, now: float) -> float | None:
        """The smallest host - device offset seen, risen by the drift allowed since."""
        if self._min_off is None:
            return None
        return self._min_off + CLOCK_DRIFT * max(now - self._min_at, 0.0)

    def unwrap(self, seq_raw: int, t_raw: int, now: float | None) -> tuple[int, int, bool]:
        """The unwrapped seq and t_us of a sample, and whether the device reset."""
        if self._seq is None or self._t_us is None:
            return seq_raw, t_raw, False
        step = (t_raw - self._raw[1]) & ((1 << self.t_bits) - 1)
        seq_step = (seq_raw - self._raw[0]) & ((1 << self.seq_bits) - 1)
        floor = None if now is None else self._floor(now)
        if now is None or floor is None or self._now is None:
            # Without host times, only a clock behind (by less than half the wrap) is a reset.
            if step < 1 << (self.t_bits - 1):
                return self._seq + seq_step, self._t_us + step, False
            return self._seq + 1, self._t_us + max(self._step_us, 1), True
        if (self._t_us + step) * 1e-6 <= now - floor + RESET_SLACK_S or self._seq_matches(
            seq_step, step
        ):
            return self._seq + seq_step, self._t_us + step, False
        return self._seq + 1, self._t_us + max(round((now - self._now) * 1e6), 1), True

    def _seq_matches(self, seq_step: int, step: int) -> bool:
        """A wide seq moved as far as the clock did, at the device's period."""
        if self.seq_bits < _SEQ_TRUSTED_BITS or self._period_us is None or seq_step == 0:
            return False
        if step >= 1 << (self.t_bits - 1) or seq_step >= 1 << (self.seq_bits - 1):
            return False  # backwards, either of them
        expect = seq_step * self._period_us
        return abs(step - expect) <= max(2 * self._period_us, 0.05 * expect)

    def keep(
        self,
        seq_raw: int,
        t_raw: int,
        now: float | None,
        seq: int,
        t_us: int,
        reset: bool,
        stats: FramingStats,
    ) -> None:
        """A good sample's counters become the ones the next sample is read against."""
        if reset:
            stats.device_resets += 1
        elif self._t_us is not None and self._seq is not None:
            self._step_us = t_us - self._t_us
            if seq > self._seq and self._step_us > 0:
                self._period_us = self._step_us / (seq - self._seq)
        if now is not None:
            off = now - t_us * 1e-6
            floor = self._floor(now)
            if floor is None or off < floor:
                self._min_off, self._min_at = off, now
        self._seq, self._t_us, self._raw, self._now = seq, t_us, (seq_raw, t_raw), now


@dataclass
class SerialFrameDecoder:
    """Incremental decoder: feed it bytes as they arrive, get complete samples back.
    Carries the 32-bit seq and 64-bit microsecond clock on over a wrap of seq and a
    device reset (:class:`DeviceCounters`): a UART device that resets sends on from
    a clock at zero, with nothing failing on the host's side."""

    stats: FramingStats = field(default_factory=FramingStats)
    counters: DeviceCounters = field(default_factory=lambda: DeviceCounters(32, 64))
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
            body = bytes(buf[2:end])
            del buf[: end + 4]
            sample = self._payload(body, now)
            if sample is None:
                self.stats.bad_payload += 1
                continue
            seq_raw, t_raw = _SERIAL_COUNTERS.unpack_from(body, 2)
            seq, t_us, reset = self.counters.unwrap(seq_raw, t_raw, now)
            self.counters.keep(seq_raw, t_raw, now, seq, t_us, reset, self.stats)
            self.stats.samples += 1
            out.append(dataclasses.replace(sample, device_seq=seq, device_t=t_us * 1e-6))

    def reset(self) -> None:
        """Drop the bytes of a frame a disconnect cut (they are never continued), and
        forget the counters: a device that came back starts them anew."""
        self.stats.skipped_bytes += len(self._buf)
        self._buf.clear()
        self.counters.reset()

    @staticmethod
    def _payload(body: bytes, now: float | None) -> TrackerSample | None:
        """A checked frame's sample (its counters as sent), or None if it is bad."""
        if body[0] == SITES_VERSION:
            return _sites_payload(body[2:], body[1], now)
        if body[0] != SERIAL_VERSION or body[1] != SERIAL_PAYLOAD_BYTES:
            return None
        seq, t_us, valid, *values = _PAYLOAD.unpack(body[2:])
        rows = np.array(values, dtype=np.float64).reshape(4, 7)
        pos, quat = rows[:, :3].copy(), rows[:, 3:].copy()
        if valid > 0b1111 or not _check_slots(pos, quat, valid):
            return None
        _untracked_to_identity(pos, quat, valid)
        return TrackerSample(pos, quat, valid, t=now, device_seq=seq, device_t=t_us * 1e-6)


def _sites_payload(payload: bytes, length: int, now: float | None) -> TrackerSample | None:
    """A version-2 serial payload, or None when it is malformed or absurd."""
    if length < _SITES_HEAD.size or len(payload) != length:
        return None
    seq, t_us, valid, n = _SITES_HEAD.unpack_from(payload)
    if not 1 <= n <= MAX_DEVICE_SITES or length != _SITES_HEAD.size + n * _SITES_ROW.size:
        return None
    rows = [
        _SITES_ROW.unpack_from(payload, _SITES_HEAD.size + i * _SITES_ROW.size) for i in range(n)
    ]
    return _sites_sample([r[0] for r in rows], [r[1:4] for r in rows], [r[4:] for r in rows],
                         valid, n, now, seq, t_us * 1e-6)  # fmt: skip


def _sites_sample(
    codes: list[int],
    values: list[Any],
    quats: list[Any],
    valid: int,
    n: int,
    now: float | None,
    seq: int,
    t_s: float,
) -> TrackerSample | None:
    names = _site_names(codes)
    pos = np.array(values, dtype=np.float64).reshape(n, 3)
    quat = np.array(quats, dtype=np.float64).reshape(n, 4) / 32767.0
    if names is None or valid > (1 << n) - 1 or not _check_slots(pos, quat, valid):
        return None
    _untracked_to_identity(pos, quat, valid)
    quat /= np.linalg.norm(quat, axis=1, keepdims=True)
    return TrackerSample(pos, quat, valid, t=now, device_seq=seq, device_t=t_s, sites=names)


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


def encode_hid_sites_report(
    seq: int,
    t_us: int,
    sites: tuple[str, ...] | list[str],
    values: F64,
    orientations: F64,
    valid: int | None = None,
) -> bytes:
    """One 161-byte tracker-set HID report (report id 2): positional rows in
    millimetres (within +-32.767 m), inertial rows in 0.01 m/s^2 (within +-327 m/s^2)."""
    n = len(sites)
    if not 1 <= n <= MAX_DEVICE_SITES:
        raise ValueError(f"1 to {MAX_DEVICE_SITES} rows, not {n}")
    codes = _site_codes(sites)
    unit = np.array([ACC_UNIT if c & INERTIAL_BIT else 0.001 for c in codes])[:, None]
    v = np.rint(np.asarray(values, dtype=np.float64) / unit)
    q = np.rint(np.asarray(orientations, dtype=np.float64) * 32767.0)
    if not ((np.abs(v) <= 32767).all() and (np.abs(q) <= 32767).all()):
        raise ValueError("a value beyond the int16 range or a quaternion beyond unit length")
    mask = (1 << n) - 1 if valid is None else valid
    report = bytearray(HID_SITES_REPORT_BYTES)
    _HID_SITES_HEAD.pack_into(
        report,
        0,
        HID_SITES_REPORT_ID,
        SITES_VERSION << 4,
        seq & 0xFF,
        0,
        t_us & 0xFFFFFFFF,
        mask,
        n,
    )
    for i in range(n):
        at = _HID_SITES_HEAD.size + i * _HID_SITES_ROW.size
        _HID_SITES_ROW.pack_into(report, at, codes[i], *map(int, v[i]), *map(int, q[i]))
    report[3] = _report_crc(bytes(report))
    return bytes(report)


@dataclass
class HidReportDecoder:
    """Decodes reports one by one; unwraps the 8-bit seq and 32-bit microsecond clock,
    and carries them on over a device reset (:class:`DeviceCounters`)."""

    stats: FramingStats = field(default_factory=FramingStats)
    counters: DeviceCounters = field(default_factory=lambda: DeviceCounters(8, 32))

    def reset(self) -> None:
        """Forget the counters: a device that came back starts them anew."""
        self.counters.reset()

    def _keep(
        self, seq8: int, t32: int, now: float | None, seq: int, t_us: int, reset: bool
    ) -> None:
        """A good sample: its counters are the ones the next report is read against."""
        self.counters.keep(seq8, t32, now, seq, t_us, reset, self.stats)
        self.stats.samples += 1

    def decode(self, report: bytes, now: float | None = None) -> TrackerSample | None:
        """A report in, its sample out (``None``, counted in ``stats``, if it is bad)."""
        if report[:1] == bytes((HID_SITES_REPORT_ID,)):
            return self._sites(report, now)
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
        seq, t_us, reset = self.counters.unwrap(seq8, t32, now)
        self._keep(seq8, t32, now, seq, t_us, reset)
        return TrackerSample(pos, quat, valid, t=now, device_seq=seq, device_t=t_us * 1e-6)

    def _sites(self, report: bytes, now: float | None) -> TrackerSample | None:
        if len(report) != HID_SITES_REPORT_BYTES:
            self.stats.bad_payload += 1
            return None
        if report[3] != _report_crc(report):
            self.stats.bad_checksum += 1
            return None
        _, vv, seq8, _, t32, valid, n = _HID_SITES_HEAD.unpack_from(report)
        if vv != SITES_VERSION << 4 or not 1 <= n <= MAX_DEVICE_SITES:
            self.stats.bad_payload += 1
            return None
        rows = [
            _HID_SITES_ROW.unpack_from(report, _HID_SITES_HEAD.size + i * _HID_SITES_ROW.size)
            for i in range(n)
        ]
        codes = [r[0] for r in rows]
        unit = [ACC_UNIT if c & INERTIAL_BIT else 0.001 for c in codes]
        values = [[x * u for x in r[1:4]] for r, u in zip(rows, unit, strict=True)]
        seq, t_us, reset = self.counters.unwrap(seq8, t32, now)
        sample = _sites_sample(
            codes, values, [r[4:] for r in rows], valid, n, now, seq, t_us * 1e-6
        )
        if sample is None:
            self.stats.bad_payload += 1
            return None
        self._keep(seq8, t32, now, seq, t_us, reset)
        return sample
