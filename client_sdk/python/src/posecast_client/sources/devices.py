"""Hardware tracker sources: a serial port (pyserial) and a USB HID device (hidapi).

Both are thin shells: a worker thread does the blocking reads, the pure decoders of
:mod:`posecast_client.sources.framing` turn bytes into samples, and each sample is
stamped with the host's ``time.monotonic()`` when its bytes arrived. The device
formats are specified in ``proto/devices.md``.

pyserial and hidapi are optional (``pip install posecast-client[serial,hid]``);
tests pass a device object instead (pyserial's ``loop://`` port, or any object with
hidapi's ``read(max_length, timeout_ms)``).
"""

from __future__ import annotations

import asyncio
import importlib
import time
from collections.abc import AsyncIterator
from typing import Any, Protocol

from posecast_client.sites import TrackerSet, as_tracker_set
from posecast_client.sources.base import TrackerSample, TrackerSource
from posecast_client.sources.framing import (
    HID_REPORT_BYTES,
    HID_SITES_REPORT_BYTES,
    FramingStats,
    HidReportDecoder,
    SerialFrameDecoder,
    to_tracker_set,
)


class SerialPort(Protocol):
    """The part of ``serial.Serial`` this source uses."""

    @property
    def in_waiting(self) -> int: ...

    def read(self, size: int = 1) -> bytes: ...

    def close(self) -> None: ...


class HidDevice(Protocol):
    """The part of ``hid.device`` this source uses."""

    def read(self, max_length: int, timeout_ms: int = 0) -> list[int] | bytes: ...

    def close(self) -> None: ...


def _optional(module: str, extra: str) -> Any:
    try:
        return importlib.import_module(module)
    except ImportError:
        raise ImportError(f"{module} is missing: pip install 'posecast-client[{extra}]'") from None


class SerialTrackerSource(TrackerSource):
    """Tracker samples from a serial port (``proto/devices.md``, "Serial").

    Args:
        url: a port (``/dev/ttyUSB0``, ``COM3``) or any pyserial URL (``loop://``).
        baudrate: bits per second (460800: a 133-byte frame at 120 Hz needs ~160 kbit/s).
        port: an already open port object instead of ``url`` (tests, custom transports).
        timeout_s: how long one blocking read waits; bounds how fast ``aclose`` returns.
        tracker_set: the player's tracker set (a layout string or a
            :class:`~posecast_client.sites.TrackerSet`): the device sends version-2
            frames of named sites, yielded in the set's row order (a site the device
            does not send is untracked); without one, version-1 frames of the four
            slots.
    """

    def __init__(
        self,
        url: str = "",
        *,
        baudrate: int = 460_800,
        port: SerialPort | None = None,
        timeout_s: float = 0.05,
        tracker_set: str | TrackerSet | None = None,
    ) -> None:
        self.tracker_set = as_tracker_set(tracker_set)
        if port is None:
            serial = _optional("serial", "serial")
            port = serial.serial_for_url(url, baudrate=baudrate, timeout=timeout_s)
        self.port: SerialPort = port
        self.decoder = SerialFrameDecoder()
        self._closed = False

    @property
    def stats(self) -> FramingStats:
        return self.decoder.stats

    def _read(self) -> bytes:
        return self.port.read(self.port.in_waiting or 1)  # blocks for the first byte only

    async def __aiter__(self) -> AsyncIterator[TrackerSample]:
        while not self._closed:
            data = await asyncio.to_thread(self._read)
            for sample in self.decoder.feed(data, time.monotonic()):
                out = _rows_for(sample, self.tracker_set, self.decoder.stats)
                if out is not None:
                    yield out

    async def aclose(self) -> None:
        self._closed = True
        self.port.close()


class HidTrackerSource(TrackerSource):
    """Tracker samples from a USB HID device (``proto/devices.md``, "HID").

    Args:
        vendor_id, product_id: the USB ids of the device to open.
        serial_number: picks one of several identical devices.
        device: an already open device object instead (tests, other HID libraries).
        timeout_ms: how long one blocking read waits; bounds how fast ``aclose`` returns.
        tracker_set: as for :class:`SerialTrackerSource` (report id 2 carries a set's
            named sites).
    """

    def __init__(
        self,
        vendor_id: int = 0,
        product_id: int = 0,
        *,
        serial_number: str | None = None,
        device: HidDevice | None = None,
        timeout_ms: int = 50,
        tracker_set: str | TrackerSet | None = None,
    ) -> None:
        self.tracker_set = as_tracker_set(tracker_set)
        if device is None:
            opened = _optional("hid", "hid").device()
            opened.open(vendor_id, product_id, serial_number)
            device = opened
        self.device: HidDevice = device
        self.decoder = HidReportDecoder()
        self.timeout_ms = timeout_ms
        self._closed = False

    @property
    def stats(self) -> FramingStats:
        return self.decoder.stats

    async def __aiter__(self) -> AsyncIterator[TrackerSample]:
        while not self._closed:
            size = HID_REPORT_BYTES if self.tracker_set is None else HID_SITES_REPORT_BYTES
            report = await asyncio.to_thread(self.device.read, size, self.timeout_ms)
            if report:  # empty: the read timed out
                sample = self.decoder.decode(bytes(report), time.monotonic())
                if sample is not None:
                    out = _rows_for(sample, self.tracker_set, self.decoder.stats)
                    if out is not None:
                        yield out

    async def aclose(self) -> None:
        self._closed = True
        self.device.close()


def _rows_for(
    sample: TrackerSample, tracker_set: TrackerSet | None, stats: FramingStats
) -> TrackerSample | None:
    """A decoded sample in the rows the source yields, or None (counted as a bad
    payload) when its format is not the one the source was opened for."""
    if (sample.sites is None) != (tracker_set is None):
        stats.bad_payload += 1
        stats.samples -= 1
        return None
    return sample if tracker_set is None else to_tracker_set(sample, tracker_set)
