"""Hardware tracker sources: a serial port (pyserial) and a USB HID device (hidapi).

Both are thin shells: a worker thread does the blocking reads, the pure decoders of
:mod:`posecast_client.sources.framing` turn bytes into samples, and each sample is
stamped with the host's ``time.monotonic()`` when its bytes arrived. The device
formats are specified in ``proto/devices.md``.

A read and the device's close never overlap: ``aclose`` waits for the read in
progress (at most one read timeout), as closing a hidapi handle under a read frees
it in use. A device that fails (unplugged, reset: the read raises ``OSError``) is
closed and, when the source opened it (by URL, or by USB ids), reopened every
``reopen_s`` seconds until it is back, each failure counted in
``stats.disconnects``; the bytes of a frame the failure cut are dropped. A device
object passed in is not reopened: its failure ends the iteration with the error. A
serial or HID device that resets with no read failing starts its counters over under
the open port or handle: the decoder carries them on (``stats.device_resets``, see
:class:`~posecast_client.sources.framing.DeviceCounters`).

pyserial and hidapi are optional (``pip install posecast-client[serial,hid]``);
tests pass a device object instead (pyserial's ``loop://`` port, or any object with
hidapi's ``read(max_length, timeout_ms)``).
"""

from __future__ import annotations

import asyncio
import contextlib
import importlib
import threading
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


class _Bridge(TrackerSource):
    """What both sources share: locked reads, a close that waits for them, reopening."""

    reopen_s = 0.5  # seconds between attempts to reopen a failed device

    def __init__(self, handle: Any, reopenable: bool) -> None:
        self._handle = handle
        self._reopenable = reopenable
        self._lock = threading.Lock()
        self._closed = False

    @property
    def stats(self) -> FramingStats:
        raise NotImplementedError

    def _open(self) -> Any:
        raise NotImplementedError

    def _restart(self) -> None:
        """Forget the decoder's state: the device came back."""

    def _locked(self, read: Any, *args: Any) -> Any:
        with self._lock:
            return None if self._closed else read(self._handle, *args)

    async def _read(self, read: Any, *args: Any) -> Any:
        """``read(handle, *args)`` in the worker thread; ``None`` when the source is
        closed or the device failed (and has been reopened)."""
        try:
            return await asyncio.to_thread(self._locked, read, *args)
        except OSError:  # pyserial's SerialException too
            if not self._reopenable or self._closed:
                raise
        self.stats.disconnects += 1
        await asyncio.to_thread(self._close_handle)
        while not self._closed:
            await asyncio.sleep(self.reopen_s)
            try:
                handle = await asyncio.to_thread(self._open)
            except OSError:
                continue
            self._adopt(handle)
            break
        return None

    def _adopt(self, handle: Any) -> None:
        """The reopened device replaces the failed one, unless the source closed meanwhile."""
        with self._lock:
            if self._closed:
                handle.close()
            else:
                self._handle = handle
                self._restart()

    def _close_handle(self) -> None:
        with self._lock, contextlib.suppress(OSError):
            self._handle.close()

    async def aclose(self) -> None:
        self._closed = True
        cancel = getattr(self._handle, "cancel_read", None)  # pyserial: end a blocking read
        if cancel is not None:
            with contextlib.suppress(Exception):
                cancel()
        await asyncio.to_thread(self._close_handle)


class SerialTrackerSource(_Bridge):
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
        self.url, self.baudrate, self.timeout_s = url, baudrate, timeout_s
        super().__init__(self._open() if port is None else port, reopenable=port is None)
        self.decoder = SerialFrameDecoder()

    @property
    def port(self) -> SerialPort:
        port: SerialPort = self._handle
        return port

    @property
    def stats(self) -> FramingStats:
        return self.decoder.stats

    def _open(self) -> SerialPort:
        serial = _optional("serial", "serial")
        port: SerialPort = serial.serial_for_url(
            self.url, baudrate=self.baudrate, timeout=self.timeout_s
        )
        return port

    def _restart(self) -> None:
        self.decoder.reset()

    @staticmethod
    def _read_port(port: SerialPort) -> bytes:
        return port.read(port.in_waiting or 1)  # blocks for the first byte only

    async def __aiter__(self) -> AsyncIterator[TrackerSample]:
        while not self._closed:
            data = await self._read(self._read_port)
            if not data:
                continue
            for sample in self.decoder.feed(data, time.monotonic()):
                out = _rows_for(sample, self.tracker_set, self.decoder.stats)
                if out is not None:
                    yield out


class HidTrackerSource(_Bridge):
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
        self.ids = (vendor_id, product_id, serial_number)
        super().__init__(self._open() if device is None else device, reopenable=device is None)
        self.decoder = HidReportDecoder()
        self.timeout_ms = timeout_ms

    @property
    def device(self) -> HidDevice:
        device: HidDevice = self._handle
        return device

    @property
    def stats(self) -> FramingStats:
        return self.decoder.stats

    def _open(self) -> HidDevice:
        device = _optional("hid", "hid").device()
        device.open(*self.ids)
        opened: HidDevice = device
        return opened

    def _restart(self) -> None:
        self.decoder.reset()

    @staticmethod
    def _read_device(device: HidDevice, size: int, timeout_ms: int) -> list[int] | bytes:
        return device.read(size, timeout_ms)

    async def __aiter__(self) -> AsyncIterator[TrackerSample]:
        while not self._closed:
            size = HID_REPORT_BYTES if self.tracker_set is None else HID_SITES_REPORT_BYTES
            report = await self._read(self._read_device, size, self.timeout_ms)
            if report:  # empty: the read timed out; None: closed, or the device came back
                sample = self.decoder.decode(bytes(report), time.monotonic())
                if sample is not None:
                    out = _rows_for(sample, self.tracker_set, self.decoder.stats)
                    if out is not None:
                        yield out


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
