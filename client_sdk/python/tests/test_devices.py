"""The serial and HID tracker sources (``sources/devices.py``): reading a port or a
device through the framing, carrying on over a device reset, closing while a read
waits, and reopening a device that failed."""

from __future__ import annotations

import asyncio
import time
from typing import Any

import numpy as np
import pytest

from device_helpers import (
    DEVICE_SITES,
    PERIOD_US,
    PLAYER_SET,
    SERIAL_PERIOD_US,
    Sent,
    assert_sample,
    one_frame,
    one_report,
    random_sample,
)
from posecast_client.sites import TrackerSet
from posecast_client.sources import HidTrackerSource, SerialTrackerSource, TrackerSample
from posecast_client.sources.framing import (
    encode_hid_report,
    encode_hid_sites_report,
    encode_serial_frame,
)


async def take(source: HidTrackerSource | SerialTrackerSource, n: int) -> list[TrackerSample]:
    """The first ``n`` samples of ``source``, which is closed after (``async with``)."""
    got: list[TrackerSample] = []
    async with source:
        async for s in source:
            got.append(s)
            if len(got) == n:
                break
    return got


# --- serial ---------------------------------------------------------------------------


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


# --- HID ------------------------------------------------------------------------------


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


# --- the device itself: closing while a read waits, failing and coming back -----------


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
