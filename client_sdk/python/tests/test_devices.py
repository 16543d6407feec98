"""Serial framing and HID reports: round trips, resynchronisation, and fuzzing.

The promise under test: corrupt bytes are skipped and never read as data. Every
decoded sample equals one that was sent, and every intact frame is found again.
"""

from __future__ import annotations

import asyncio
import re
import time
import zlib
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from posecast_client.rotations import quat_normalize
from posecast_client.sites import TrackerSet
from posecast_client.sources import HidTrackerSource, SerialTrackerSource, TrackerSample
from posecast_client.sources.framing import (
    HID_REPORT_BYTES,
    HID_SITES_REPORT_BYTES,
    SERIAL_FRAME_BYTES,
    SERIAL_SYNC,
    DeviceCounters,
    FramingStats,
    HidReportDecoder,
    SerialFrameDecoder,
    crc8,
    encode_hid_report,
    encode_hid_sites_report,
    encode_serial_frame,
    encode_serial_sites,
    to_tracker_set,
)

Sent = dict[int, tuple[np.ndarray, np.ndarray, int]]


def random_sample(rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray, int]:
    pos = rng.uniform(-3.0, 3.0, (4, 3))
    quat = quat_normalize(rng.normal(size=(4, 4)))
    return pos, quat, int(rng.integers(0, 16))


def expected(pos: np.ndarray, quat: np.ndarray, valid: int, step: float | None) -> np.ndarray:
    """What a decoder must return: the wire precision, untracked slots as identity."""
    if step is None:  # float32 on the serial line
        p, q = pos.astype(np.float32).astype(np.float64), quat.astype(np.float32).astype(np.float64)
    else:  # HID: millimetres and int16 quaternions
        p, q = np.rint(pos * 1000) * 0.001, np.rint(quat * 32767) / 32767
    for i in range(4):
        if not valid >> i & 1:
            p[i], q[i] = 0.0, (0.0, 0.0, 0.0, 1.0)
    return np.hstack([p, q])


def assert_sample(s: TrackerSample, sent: Sent, step: float | None) -> None:
    assert s.device_seq is not None and s.device_seq in sent, s.device_seq
    pos, quat, valid = sent[s.device_seq]
    assert s.valid == valid
    got = np.hstack([s.positions, s.orientations])
    np.testing.assert_allclose(got, expected(pos, quat, valid, step), rtol=0, atol=1e-12)


async def take(source: HidTrackerSource | SerialTrackerSource, n: int) -> list[TrackerSample]:
    """The first ``n`` samples of ``source``, which is closed after (``async with``)."""
    got: list[TrackerSample] = []
    async with source:
        async for s in source:
            got.append(s)
            if len(got) == n:
                break
    return got


# --- serial ------------------------------------------------------------------------


def test_serial_frame_round_trip(rng: np.random.Generator) -> None:
    pos, quat, valid = random_sample(rng)
    frame = encode_serial_frame(7, 1_234_567, pos, quat, valid)
    assert len(frame) == SERIAL_FRAME_BYTES and frame.startswith(SERIAL_SYNC)
    dec = SerialFrameDecoder()
    (s,) = dec.feed(frame, now=5.0)
    assert (s.t, s.device_seq) == (5.0, 7) and s.device_t == pytest.approx(1.234567)
    assert_sample(s, {7: (pos, quat, valid)}, None)
    assert dec.feed(frame[:50]) == [] and len(dec.feed(frame[50:])) == 1  # split reads
    assert dec.feed(frame[1:]) == [] and len(dec.feed(frame)) == 1  # no sync: skipped


def test_serial_fuzz_garbage_cut_and_corrupt_frames(rng: np.random.Generator) -> None:
    sent: Sent = {}
    intact: set[int] = set()
    stream = bytearray()
    for seq in range(600):
        if rng.random() < 0.4:  # garbage, with stray sync bytes and lengths in it
            junk = bytearray(rng.integers(0, 256, int(rng.integers(1, 300)), dtype=np.uint8))
            for _ in range(int(rng.integers(0, 3))):
                at = int(rng.integers(0, len(junk)))
                junk[at:at] = SERIAL_SYNC + bytes([1, int(rng.integers(0, 256))])
            stream += junk
        pos, quat, valid = random_sample(rng)
        sent[seq] = (pos, quat, valid)
        frame = bytearray(encode_serial_frame(seq, seq * 16_667, pos, quat, valid))
        fate = rng.random()
        if fate < 0.1:
            frame = frame[: int(rng.integers(1, len(frame)))]  # cut short
        elif fate < 0.2:
            at = int(rng.integers(0, len(frame)))
            frame[at] ^= 1 << int(rng.integers(0, 8))  # one bit flipped
        else:
            intact.add(seq)
        stream += frame
    dec = SerialFrameDecoder()
    got: list[TrackerSample] = []
    i = 0
    while i < len(stream):  # arbitrary read sizes
        n = int(rng.integers(1, 400))
        got += dec.feed(bytes(stream[i : i + n]))
        i += n
    for s in got:
        assert_sample(s, sent, None)
    assert [s.device_seq for s in got] == sorted(intact)
    assert dec.stats.samples == len(intact) and dec.stats.bad_checksum > 0


def test_serial_random_garbage_alone_yields_nothing(rng: np.random.Generator) -> None:
    dec = SerialFrameDecoder()
    for _ in range(50):
        junk = rng.integers(0, 256, 4000, dtype=np.uint8).tobytes()
        assert dec.feed(junk.replace(b"\xa5", b"\xa5\x5a\x01\x7d")) == []


def test_serial_source_reads_a_loop_port(rng: np.random.Generator) -> None:
    pytest.importorskip("serial")
    sent: Sent = {k: random_sample(rng) for k in range(30)}
    source = SerialTrackerSource("loop://", timeout_s=0.02)
    port: Any = source.port  # a pyserial loop port: what is written comes back

    def write_all() -> None:  # the loop port's buffer is small: write while reading
        for seq, (pos, quat, valid) in sent.items():
            port.write(rng.integers(0, 256, int(rng.integers(0, 40)), dtype=np.uint8).tobytes())
            port.write(encode_serial_frame(seq, seq * 1000, pos, quat, valid))

    async def read_all() -> list[TrackerSample]:
        writer = asyncio.create_task(asyncio.to_thread(write_all))
        got = await take(source, len(sent))
        await writer
        return got

    got = asyncio.run(asyncio.wait_for(read_all(), 10.0))
    for s in got:
        assert_sample(s, sent, None)
        assert s.t is not None
    assert [s.device_seq for s in got] == list(sent)


SERIAL_PERIOD_US = 8_333  # a 120 Hz device


def one_frame(kind: str, seq: int, t_us: int) -> bytes:
    """A version-1 (four slots) or tracker-set serial frame; only its counters matter."""
    if kind == "slots":
        return encode_serial_frame(
            seq, t_us, np.zeros((4, 3)), np.tile([0.0, 0.0, 0.0, 1.0], (4, 1))
        )
    return encode_serial_sites(seq, t_us, ["head"], np.zeros((1, 3)), np.array([[0, 0, 0, 1.0]]))


def _assert_carried_on(samples: list[TrackerSample], period_us: int, atol: float) -> None:
    """Three samples from seq 40, a device reset, three from seq 0: seq carries on by
    one and device_t by one device period a step (the serial and HID cases alike)."""
    assert [s.device_seq for s in samples] == [40, 41, 42, 43, 44, 45]
    times = [s.device_t for s in samples if s.device_t is not None]
    np.testing.assert_allclose(np.diff(times), [period_us * 1e-6] * 5, rtol=0, atol=atol)


@pytest.mark.parametrize("kind", ["slots", "sites"])
@pytest.mark.parametrize("uptime_s", [5.0, 3000.0, 864_000.0])
def test_a_serial_device_reset_carries_the_counters_on(kind: str, uptime_s: float) -> None:
    """A device on a UART resets with nothing failing on the host's side and sends on
    from seq 0 and t_us 0: device_t went back by its uptime (up to days) and seq to 0.
    Both carry on instead, by the host's time between the frames and by one, as HID."""
    dec = SerialFrameDecoder()
    host, up_us = 100.0, int(uptime_s * 1e6)
    got = []
    for k in range(3):
        got += dec.feed(one_frame(kind, 40 + k, up_us + k * SERIAL_PERIOD_US), host + k / 120)
    for k in range(3):
        got += dec.feed(one_frame(kind, k, (k + 1) * SERIAL_PERIOD_US), host + (3 + k) / 120)
    assert len(got) == 6 and dec.stats.samples == 6
    _assert_carried_on(got, SERIAL_PERIOD_US, atol=1e-6)
    assert dec.stats.device_resets == 1


def test_serial_without_host_times_a_clock_that_steps_back_is_a_reset() -> None:
    dec = SerialFrameDecoder()
    frames = [one_frame("slots", 40 + k, 5_000_000 + k * SERIAL_PERIOD_US) for k in range(3)]
    frames += [one_frame("slots", k, (k + 1) * SERIAL_PERIOD_US) for k in range(3)]
    got = dec.feed(b"".join(frames))  # one read, no host time
    _assert_carried_on(got, SERIAL_PERIOD_US, atol=1e-9)
    assert dec.stats.device_resets == 1


def test_a_serial_seq_wrap_is_no_reset_even_for_frames_that_queued() -> None:
    """The 32-bit seq wraps (every 414 days at 120 Hz): device_seq goes on counting.
    Frames that waited in the host's buffer come in one read, a period apart in device
    time; a second of the device's backlog arriving at once is no reset either."""
    dec = SerialFrameDecoder()
    start_us = 2**40
    frames = [one_frame("slots", 2**32 - 2 + k, start_us + k * SERIAL_PERIOD_US) for k in range(4)]
    got = dec.feed(frames[0], 10.0) + dec.feed(b"".join(frames[1:]), 10.0)
    assert [s.device_seq for s in got] == [2**32 - 2, 2**32 - 1, 2**32, 2**32 + 1]
    late = [one_frame("slots", k + 2, start_us + (k + 4) * SERIAL_PERIOD_US) for k in range(120)]
    got += dec.feed(b"".join(late), 11.0)
    assert [s.device_seq for s in got] == list(range(2**32 - 2, 2**32 + 122))
    assert dec.stats.device_resets == 0
    for k, s in enumerate(got):
        assert s.device_t == pytest.approx((start_us + k * SERIAL_PERIOD_US) * 1e-6, abs=1e-6)


def test_the_serial_source_carries_on_over_a_device_reset() -> None:
    """The port stays open (no read failed): the decoder re-anchors. A reopened port
    starts the counters anew (decoder.reset)."""
    frames = [one_frame("slots", 40 + k, 5_000_000 + k * SERIAL_PERIOD_US) for k in range(3)]
    frames += [one_frame("slots", k, (k + 1) * SERIAL_PERIOD_US) for k in range(3)]

    class Port:
        in_waiting = 0

        def read(self, size: int = 1) -> bytes:
            return frames.pop(0) if frames else b""

        def close(self) -> None:
            pass

    source = SerialTrackerSource(port=Port(), timeout_s=0.01)
    got = asyncio.run(asyncio.wait_for(take(source, 6), 10.0))
    assert [s.device_seq for s in got] == [40, 41, 42, 43, 44, 45]
    assert source.stats.device_resets == 1 and source.stats.disconnects == 0
    a, b = got[2], got[3]  # across the reset: the host's time between them
    assert a.t is not None and b.t is not None and a.device_t is not None and b.device_t is not None
    assert b.device_t - a.device_t == pytest.approx(max(b.t - a.t, 1e-6), abs=1e-6)
    source.decoder.reset()  # the device came back on a reopened port: counters anew
    (s,) = source.decoder.feed(one_frame("slots", 7, 1000), 200.0)
    assert (s.device_seq, s.device_t) == (7, 0.001)


# --- HID ---------------------------------------------------------------------------


class FakeHid:
    """Stands in for ``hid.device``: hands out queued reports, then times out."""

    def __init__(self, reports: list[bytes]) -> None:
        self.reports = list(reports)
        self.closed = False

    def read(self, max_length: int, timeout_ms: int = 0) -> list[int]:
        if not self.reports:
            return []
        return list(self.reports.pop(0)[:max_length])

    def close(self) -> None:
        self.closed = True


def test_hid_report_layout(rng: np.random.Generator) -> None:
    pos, quat, valid = random_sample(rng)
    report = encode_hid_report(300, 2**32 + 5, pos, quat, valid)  # both wrap
    assert len(report) == HID_REPORT_BYTES and report[0] == 1 and report[1] == 0x10 | valid
    assert (report[2], report[3]) == (300 & 0xFF, crc8(report[:3] + report[4:]))
    s = HidReportDecoder().decode(report, now=1.0)
    assert s is not None
    assert_sample(s, {44: (pos, quat, valid)}, 0.001)
    assert crc8(b"123456789") == 0xF4  # the CRC-8/SMBUS check value
    with pytest.raises(ValueError):
        encode_hid_report(0, 0, pos + 40.0, quat)


def test_hid_source_skips_garbage_and_unwraps_counters(rng: np.random.Generator) -> None:
    sent: Sent = {}
    reports: list[bytes] = []
    good = 0
    for k in range(600):
        seq, t_us = 250 + k, (2**32 - 5_000_000 + k * 16_667)  # both wrap around mid-way
        pos, quat, valid = random_sample(rng)
        report = bytearray(encode_hid_report(seq, t_us, pos, quat, valid))
        fate = rng.random()
        if fate < 0.1:
            report[int(rng.integers(0, 64))] ^= 1 << int(rng.integers(0, 8))
        elif fate < 0.15:
            report = report[: int(rng.integers(1, 64))]
        elif fate < 0.2:
            report = bytearray(rng.integers(0, 256, 64, dtype=np.uint8).tobytes())
        else:
            sent[seq] = (pos, quat, valid)
            good += 1
        reports.append(bytes(report))
    device = FakeHid(reports)
    source = HidTrackerSource(device=device, timeout_ms=1)

    got = asyncio.run(asyncio.wait_for(take(source, good), 20.0))
    assert device.closed
    for s in got:
        assert_sample(s, sent, 0.001)
    assert [s.device_seq for s in got] == sorted(sent)
    times = np.array([s.device_t for s in got], dtype=float)
    assert (np.diff(times) > 0).all()  # the 32-bit microsecond clock unwrapped


def test_hid_source_opens_by_vendor_and_product_id() -> None:
    pytest.importorskip("hid")
    with pytest.raises(OSError):  # no such device here
        HidTrackerSource(0x1209, 0x0001)


def test_the_examples_in_devices_md_are_what_the_encoders_write() -> None:
    doc = Path(__file__).resolve().parents[3] / "proto" / "devices.md"
    if not doc.exists():
        pytest.skip("proto/devices.md not found (repo only)")
    blocks = [b for b in re.findall(r"```\n(.*?)```", doc.read_text("utf-8"), re.DOTALL)
              if re.fullmatch(r"[0-9a-f\s]+", b)]  # fmt: skip
    serial_hex, hid_hex, serial2_hex, hid2_hex = ("".join(b.split()) for b in blocks)
    pos = np.array([[0, 1.6, 0], [0.3, 1.0, 0.1], [-0.3, 1.0, 0.1], [0, 1.0, 0]])
    quat = np.tile([0.0, 0.0, 0.0, 1.0], (4, 1))
    assert encode_serial_frame(1, 16667, pos, quat).hex() == serial_hex
    assert encode_hid_report(1, 16667, pos, quat).hex() == hid_hex
    sites = ["head", "left_hand", "right_hand", "left_foot:imu", "right_foot:imu"]
    values = np.vstack([pos[:3], [[0, 9.5, 0], [0.5, 0, -1.25]]])
    quat5 = np.tile([0.0, 0.0, 0.0, 1.0], (5, 1))
    assert encode_serial_sites(1, 16667, sites, values, quat5).hex() == serial2_hex
    assert encode_hid_sites_report(1, 16667, sites, values, quat5).hex() == hid2_hex
    (s,) = SerialFrameDecoder().feed(bytes.fromhex(serial2_hex))
    assert s.sites == tuple(sites)
    assert zlib.crc32(b"123456789") == 0xCBF43926


# --- version 2: tracker sets ---------------------------------------------------------

DEVICE_SITES = ("left_foot:imu", "head", "right_foot:imu", "left_hand", "right_hand", "waist")
PLAYER_SET = "head,left_hand,right_hand,waist,left_foot:imu,right_foot:imu,left_knee"


def random_set_sample(rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    values = rng.uniform(-3.0, 3.0, (len(DEVICE_SITES), 3))
    values[[0, 2]] *= 5.0  # accelerations, m/s^2
    return values, quat_normalize(rng.normal(size=(len(DEVICE_SITES), 4)))


def test_serial_sites_frames_round_trip_through_garbage(rng: np.random.Generator) -> None:
    dec = SerialFrameDecoder()
    sent = [random_set_sample(rng) for _ in range(40)]
    stream = b"".join(
        rng.integers(0, 256, int(rng.integers(0, 30)), dtype=np.uint8).tobytes()
        + encode_serial_sites(k, k * 16_667, DEVICE_SITES, v, q, valid=0b111011 if k % 5 else None)
        for k, (v, q) in enumerate(sent)
    )
    got = [s for i in range(0, len(stream), 37) for s in dec.feed(stream[i : i + 37])]
    assert [s.device_seq for s in got] == list(range(40))
    for s in got:
        v, q = sent[s.device_seq or 0]
        assert s.sites == DEVICE_SITES
        for i in range(len(DEVICE_SITES)):
            if s.valid >> i & 1:
                np.testing.assert_allclose(s.positions[i], v[i], rtol=1e-6, atol=1e-5)
                assert np.abs(np.abs((s.orientations[i] * q[i]).sum()) - 1.0) < 1e-8
            else:
                np.testing.assert_array_equal(s.positions[i], 0.0)
    assert dec.stats.bad_payload == 0


def test_sites_rows_in_the_players_set_order() -> None:
    ts = TrackerSet.parse(PLAYER_SET)
    v = np.arange(18, dtype=float).reshape(6, 3)
    q = np.tile([0.0, 0.0, 0.0, 1.0], (6, 1))
    (s,) = SerialFrameDecoder().feed(encode_serial_sites(1, 0, DEVICE_SITES, v, q))
    out = to_tracker_set(s, ts)
    # head, hands, waist, the IMUs, then the knee the device does not send (untracked)
    np.testing.assert_array_equal(out.positions[:6], v[[1, 3, 4, 5, 0, 2]])
    assert out.valid == 0b0111111 and out.sites == tuple(PLAYER_SET.split(","))
    # A positional left foot in the set does not take the device's inertial one.
    other = to_tracker_set(s, TrackerSet.parse("head,left_hand,right_hand,left_foot"))
    assert other.valid == 0b0111


def test_bad_sites_frames_are_dropped() -> None:
    v, q = np.zeros((2, 3)), np.tile([0.0, 0.0, 0.0, 1.0], (2, 1))
    dec = SerialFrameDecoder()
    twice = encode_serial_sites(1, 0, ["head", "head"], v, q)  # a site listed twice
    beyond = encode_serial_sites(2, 0, ["head", "waist"], v, q, valid=0b100)
    far = encode_serial_sites(3, 0, ["head", "waist"], v + 2000.0, q)
    assert dec.feed(twice + beyond + far) == []
    assert dec.stats.bad_payload == 3 and dec.stats.bad_checksum == 0


def test_hid_sites_reports(rng: np.random.Generator) -> None:
    v, q = random_set_sample(rng)
    report = encode_hid_sites_report(7, 123, DEVICE_SITES, v, q)
    assert len(report) == HID_SITES_REPORT_BYTES == 161 and report[0] == 2
    dec = HidReportDecoder()
    s = dec.decode(report)
    assert s is not None and s.sites == DEVICE_SITES and s.device_seq == 7
    inertial = np.array(["imu" in n for n in DEVICE_SITES])
    err = np.abs(s.positions - v)
    assert (err[inertial] <= 0.005 + 1e-9).all() and (err[~inertial] <= 0.0005 + 1e-9).all()
    bad = bytearray(report)
    bad[50] ^= 4
    assert dec.decode(bytes(bad)) is None and dec.stats.bad_checksum == 1


PERIOD_US = 16_667  # a 60 Hz device


def one_report(kind: str, seq: int, t_us: int) -> bytes:
    """A version-1 (four slots) or tracker-set HID report; only its counters matter."""
    if kind == "slots":
        return encode_hid_report(seq, t_us, np.zeros((4, 3)), np.tile([0.0, 0.0, 0.0, 1.0], (4, 1)))
    return encode_hid_sites_report(
        seq, t_us, ["head"], np.zeros((1, 3)), np.array([[0, 0, 0, 1.0]])
    )


@pytest.mark.parametrize("kind", ["slots", "sites"])
@pytest.mark.parametrize("uptime_s", [5.0, 3000.0, 4290.0])
def test_a_device_reset_under_an_open_handle_carries_the_counters_on(
    kind: str, uptime_s: float
) -> None:
    """A device that resets while the bridge holds it open starts seq and t_us over.
    Read as a wrap, its device_t went up to 71.6 minutes ahead (71.5 after 5 s of
    uptime; 21.6 after 3000 s; 5 s after 4290 s, just short of a wrap); it goes on by
    the host's time between the reports instead, and seq by one."""
    dec = HidReportDecoder()
    host, up_us = 100.0, int(uptime_s * 1e6)
    got = [
        dec.decode(one_report(kind, 40 + k, up_us + k * PERIOD_US), host + k / 60) for k in range(3)
    ]
    got += [
        dec.decode(one_report(kind, k, (k + 1) * PERIOD_US), host + (3 + k) / 60) for k in range(3)
    ]
    samples = [s for s in got if s is not None]
    assert len(samples) == 6 and dec.stats.samples == 6
    _assert_carried_on(samples, PERIOD_US, atol=1e-6)
    assert dec.stats.device_resets == 1


def test_without_host_times_a_clock_that_steps_back_is_a_reset() -> None:
    dec = HidReportDecoder()
    reports = [one_report("slots", 40 + k, 5_000_000 + k * PERIOD_US) for k in range(3)]
    reports += [one_report("slots", k, (k + 1) * PERIOD_US) for k in range(3)]
    samples = [dec.decode(r) for r in reports]
    _assert_carried_on([s for s in samples if s is not None], PERIOD_US, atol=1e-9)
    assert dec.stats.device_resets == 1


def test_a_wrap_is_no_reset_even_for_reports_that_queued() -> None:
    """The 32-bit clock wraps every 71.6 minutes; reports that waited in the host's queue
    arrive together, their device times still a period apart. Neither is a reset."""
    dec = HidReportDecoder()
    start = 2**32 - 2 * PERIOD_US - 5
    for k in range(6):
        s = dec.decode(one_report("slots", 254 + k, start + k * PERIOD_US), 100.0 + (k // 3) / 60)
        assert s is not None and s.device_t is not None
        assert s.device_seq == 254 + k and s.device_t == pytest.approx(
            (start + k * PERIOD_US) * 1e-6
        )
    assert dec.stats.device_resets == 0


def test_a_host_stall_is_no_device_reset() -> None:
    """The consumer stalls for 5 s; hidraw (64 reports) and the tty buffer drop the
    newest data when full, so the host reads the queued samples at once and then a
    fresh one whose clock moved by the whole stall while the host's moved by a
    millisecond. That is no reset: device_t goes on as the device sent it (it was
    4.75 s behind for good, counted as a reset)."""
    c, stats = DeviceCounters(32, 64), FramingStats()

    def feed(seq: int, t_us: int, now: float) -> tuple[int, int]:
        s, t, reset = c.unwrap(seq, t_us, now)
        c.keep(seq, t_us, now, s, t, reset, stats)
        return s, t

    feed(0, 0, 0.0)
    for k in range(1, 31):
        feed(k, k * SERIAL_PERIOD_US, 5.0 + k * 1e-6)
    assert feed(600, 600 * SERIAL_PERIOD_US, 5.001) == (600, 600 * SERIAL_PERIOD_US)
    assert stats.device_resets == 0

    hid = HidReportDecoder()  # the same through the HID decoder (8-bit seq, 32-bit clock)
    got = [hid.decode(one_report("slots", 0, 7_000_000), 0.0)]
    for k in range(1, 65):
        got.append(hid.decode(one_report("slots", k, 7_000_000 + k * PERIOD_US), 5.0))
    got.append(hid.decode(one_report("slots", 300, 7_000_000 + 300 * PERIOD_US), 5.001))
    last = got[-1]
    assert last is not None and hid.stats.device_resets == 0
    assert (last.device_seq, last.device_t) == (300, pytest.approx(7.0 + 300 * PERIOD_US * 1e-6))

    ser = SerialFrameDecoder()
    out = ser.feed(one_frame("sites", 0, 0), 0.0)
    queued = b"".join(one_frame("sites", k, k * SERIAL_PERIOD_US) for k in range(1, 31))
    out += ser.feed(queued, 5.0)
    out += ser.feed(one_frame("sites", 600, 600 * SERIAL_PERIOD_US), 5.001)
    assert ser.stats.device_resets == 0
    assert (out[-1].device_seq, out[-1].device_t) == (600, 600 * SERIAL_PERIOD_US * 1e-6)
    # A real reset after the stall is still one.
    out = ser.feed(one_frame("sites", 0, 1000), 5.01)
    assert ser.stats.device_resets == 1 and out[0].device_seq == 601


def test_a_serial_frame_ahead_whose_seq_moved_as_far_is_no_reset() -> None:
    """A port opened on a buffer the device filled before: the first frames are stale,
    so the smallest offset seen is too high and the fresh frame after them claims a
    time seconds ahead of it. Its seq moved by as many periods as its clock: no reset.
    A HID seq (8 bits) cannot tell; there the step, seconds ahead, is a reset."""
    dec = SerialFrameDecoder()
    stale = b"".join(one_frame("slots", k, k * SERIAL_PERIOD_US) for k in range(30))
    got = dec.feed(stale, 5.0) + dec.feed(one_frame("slots", 600, 600 * SERIAL_PERIOD_US), 5.001)
    assert dec.stats.device_resets == 0
    assert (got[-1].device_seq, got[-1].device_t) == (600, 600 * SERIAL_PERIOD_US * 1e-6)
    # From now on the offset is the fresh frame's: a seq that matches no longer hides
    # a clock that runs seconds ahead of the host's.
    got = dec.feed(one_frame("slots", 601, 900 * SERIAL_PERIOD_US), 5.01)  # 2.5 s ahead
    assert dec.stats.device_resets == 1 and got[0].device_seq == 601


def test_a_device_clock_slower_than_the_hosts_is_no_reset_and_resets_are_still_seen() -> None:
    """A device clock 500 ppm slow falls behind the host's by 18 s in 10 hours: no
    reset, and the smallest offset follows it up, so a reset 5 s short of the clock's
    wrap (read as a wrap, 5 s ahead) is still seen."""
    dec = HidReportDecoder()
    n = 36_000  # 10 hours at 1 Hz
    start = 2**32 - 5_000_000 - (n - 1) * 999_500  # the last report 5 s short of the wrap
    for k in range(n):
        assert dec.decode(one_report("slots", k, (start + k * 999_500) % 2**32), float(k))
    assert dec.stats.device_resets == 0
    dec.decode(one_report("slots", 0, 1000), float(n))  # reset: seq and clock from zero
    assert dec.stats.device_resets == 1


def test_the_hid_source_carries_on_over_a_device_reset() -> None:
    """The bridge keeps the device open (no read failed): the decoder re-anchors."""
    reports = [one_report("slots", 40 + k, 5_000_000 + k * PERIOD_US) for k in range(3)]
    reports += [one_report("slots", k, (k + 1) * PERIOD_US) for k in range(3)]
    source = HidTrackerSource(device=FakeHid(reports), timeout_ms=1)
    got = asyncio.run(asyncio.wait_for(take(source, 6), 10.0))
    assert [s.device_seq for s in got] == [40, 41, 42, 43, 44, 45]
    assert source.stats.device_resets == 1 and source.stats.disconnects == 0
    a, b = got[2], got[3]  # across the reset: the host's time between them
    assert a.t is not None and b.t is not None and a.device_t is not None and b.device_t is not None
    assert b.device_t - a.device_t == pytest.approx(max(b.t - a.t, 1e-6), abs=1e-6)


def test_a_sites_source_refuses_four_slot_frames_and_reorders_sets() -> None:
    ts = TrackerSet.parse(PLAYER_SET)
    v, q = np.zeros((6, 3)), np.tile([0.0, 0.0, 0.0, 1.0], (6, 1))
    reports = [
        encode_hid_report(0, 0, np.zeros((4, 3)), np.tile([0.0, 0.0, 0.0, 1.0], (4, 1))),
        encode_hid_sites_report(1, 0, DEVICE_SITES, v, q),
    ]
    source = HidTrackerSource(device=FakeHid(reports), timeout_ms=1, tracker_set=ts)

    async def first() -> TrackerSample:
        async with source:
            async for s in source:
                return s
        raise AssertionError("no sample")

    s = asyncio.run(asyncio.wait_for(first(), 10.0))
    assert s.positions.shape == (7, 3) and s.device_seq == 1
    assert source.stats.bad_payload == 1 and source.stats.samples == 1


# --- the device itself: closing while a read waits, failing and coming back ----------


class SlowHid(FakeHid):
    """A read that waits its whole timeout; records a close that lands inside a read
    (which frees a hidapi handle under the reading thread)."""

    def __init__(self) -> None:
        super().__init__([])
        self.reading = 0
        self.closed_mid_read = False

    def read(self, max_length: int, timeout_ms: int = 0) -> list[int]:
        self.reading += 1
        time.sleep(timeout_ms / 1000)
        self.reading -= 1
        return []

    def close(self) -> None:
        self.closed_mid_read = self.closed_mid_read or self.reading > 0
        super().close()


def test_closing_waits_for_the_read_in_progress() -> None:
    async def main() -> tuple[SlowHid, SlowHid]:
        cancelled, closed = SlowHid(), SlowHid()
        first = HidTrackerSource(device=cancelled, timeout_ms=100)

        async def stream() -> None:  # `async with source: await client.stream(source)`
            async with first:
                async for _ in first:
                    pass

        task = asyncio.create_task(stream())
        await asyncio.sleep(0.03)
        task.cancel()  # Ctrl-C: the read's thread runs on, __aexit__ closes
        with pytest.raises(asyncio.CancelledError):
            await task
        second = HidTrackerSource(device=closed, timeout_ms=100)

        async def drain() -> None:
            async for _ in second:
                pass

        reader = asyncio.create_task(drain())
        await asyncio.sleep(0.03)
        await second.aclose()  # from another task: the iteration just ends
        await asyncio.wait_for(reader, 2.0)
        return cancelled, closed

    for device in asyncio.run(main()):
        assert device.closed and not device.closed_mid_read


class FailingHid(FakeHid):
    """A device whose queue may hold an OSError: the read that reaches it raises."""

    def __init__(self, reports: list[bytes | OSError]) -> None:
        self.queue = list(reports)
        self.closed = False

    def open(self, vendor_id: int, product_id: int, serial_number: str | None = None) -> None:
        pass

    def read(self, max_length: int, timeout_ms: int = 0) -> list[int]:
        if not self.queue:
            return []
        item = self.queue.pop(0)
        if isinstance(item, OSError):
            raise item
        return list(item)


def test_an_unplugged_device_is_reopened_when_it_is_back(
    rng: np.random.Generator, monkeypatch: pytest.MonkeyPatch
) -> None:
    hid = pytest.importorskip("hid")
    pos, quat, valid = random_sample(rng)
    plugs: list[list[bytes | OSError]] = [
        [encode_hid_report(k, k * 16_667, pos, quat, valid) for k in range(3)]
        + [OSError("read error")],
        [encode_hid_report(200 + k, k * 16_667, pos, quat, valid) for k in range(3)],
    ]
    attempts = iter([OSError("open failed"), *plugs[1:]])  # not back at the first try

    def device() -> FailingHid:
        item = next(attempts)
        if isinstance(item, OSError):
            raise item
        return FailingHid(item)

    monkeypatch.setattr(hid, "device", lambda: FailingHid(plugs[0]))
    source = HidTrackerSource(0x1209, 0x0001, timeout_ms=1)
    source.reopen_s = 0.01
    monkeypatch.setattr(hid, "device", device)

    got = asyncio.run(asyncio.wait_for(take(source, 6), 10.0))
    # The counters restart with the device: 200 is not read as 200 + 256 k.
    assert [s.device_seq for s in got] == [0, 1, 2, 200, 201, 202]
    assert got[3].device_t == 0.0 and source.stats.disconnects == 1


def test_a_serial_port_that_fails_is_reopened(
    rng: np.random.Generator, monkeypatch: pytest.MonkeyPatch
) -> None:
    serial = pytest.importorskip("serial")
    pos, quat, valid = random_sample(rng)
    frames = [encode_serial_frame(k, k, pos, quat, valid) for k in range(4)]

    class Port:
        def __init__(self, chunks: list[bytes | OSError]) -> None:
            self.chunks = chunks
            self.closed = False

        @property
        def in_waiting(self) -> int:
            return 0

        def read(self, size: int = 1) -> bytes:
            if not self.chunks:
                return b""
            item = self.chunks.pop(0)
            if isinstance(item, OSError):
                raise item
            return item

        def close(self) -> None:
            self.closed = True

    # The first port dies mid-frame; the rest of that frame never comes.
    first = Port([frames[0], frames[1][:50], serial.SerialException("device disconnected")])
    ports = iter([first, serial.SerialException("no such port"), Port([frames[2], frames[3]])])

    def serial_for_url(url: str, **kw: Any) -> Port:
        item = next(ports)
        if isinstance(item, OSError):
            raise item
        return item

    monkeypatch.setattr(serial, "serial_for_url", serial_for_url)
    source = SerialTrackerSource("/dev/ttyUSB9")
    source.reopen_s = 0.01

    got = asyncio.run(asyncio.wait_for(take(source, 3), 10.0))
    assert [s.device_seq for s in got] == [0, 2, 3] and first.closed
    assert source.stats.disconnects == 1 and source.stats.bad_checksum == 0
