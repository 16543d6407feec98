"""Serial framing and HID reports (``sources/framing.py``, pure): round trips,
resynchronisation, fuzzing, and the device counters across resets and wraps.

The promise under test: corrupt bytes are skipped and never read as data. Every
decoded sample equals one that was sent, and every intact frame is found again.
"""

from __future__ import annotations

import re
import zlib
from pathlib import Path

import numpy as np
import pytest

from device_helpers import (
    DEVICE_SITES,
    PERIOD_US,
    PLAYER_SET,
    SERIAL_PERIOD_US,
    Sent,
    assert_carried_on,
    assert_sample,
    one_frame,
    one_report,
    random_sample,
    random_set_sample,
)
from posecast_client.sites import TrackerSet
from posecast_client.sources import TrackerSample
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

# --- serial ---------------------------------------------------------------------------


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
    assert_carried_on(got, SERIAL_PERIOD_US, atol=1e-6)
    assert dec.stats.device_resets == 1


def test_serial_without_host_times_a_clock_that_steps_back_is_a_reset() -> None:
    dec = SerialFrameDecoder()
    frames = [one_frame("slots", 40 + k, 5_000_000 + k * SERIAL_PERIOD_US) for k in range(3)]
    frames += [one_frame("slots", k, (k + 1) * SERIAL_PERIOD_US) for k in range(3)]
    got = dec.feed(b"".join(frames))  # one read, no host time
    assert_carried_on(got, SERIAL_PERIOD_US, atol=1e-9)
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


# --- HID ------------------------------------------------------------------------------


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


# --- version 2: tracker sets ----------------------------------------------------------


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


# --- the counters: device resets, wraps, stalls and drift -----------------------------


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
    assert_carried_on(samples, PERIOD_US, atol=1e-6)
    assert dec.stats.device_resets == 1


def test_without_host_times_a_clock_that_steps_back_is_a_reset() -> None:
    dec = HidReportDecoder()
    reports = [one_report("slots", 40 + k, 5_000_000 + k * PERIOD_US) for k in range(3)]
    reports += [one_report("slots", k, (k + 1) * PERIOD_US) for k in range(3)]
    samples = [dec.decode(r) for r in reports]
    assert_carried_on([s for s in samples if s is not None], PERIOD_US, atol=1e-9)
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
