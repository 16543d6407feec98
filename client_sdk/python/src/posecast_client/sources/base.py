"""What every tracker source yields: one :class:`TrackerSample` per frame."""

from __future__ import annotations

import abc
from collections.abc import AsyncIterator
from dataclasses import dataclass
from types import TracebackType

import numpy as np
from numpy.typing import NDArray

F64 = NDArray[np.float64]


@dataclass(frozen=True, slots=True, eq=False)
class TrackerSample:
    """One frame of the four trackers, in slot order HEAD, LEFT_HAND, RIGHT_HAND, WAIST
    (or of a tracker set's sites, in the set's order).

    Attributes:
        positions: ``(4, 3)`` world metres (+Y up); a set's ``(n, 3)``, an inertial
            site's row its world acceleration, m/s^2.
        orientations: ``(4, 4)`` world xyzw (a set's ``(n, 4)``).
        valid: bit ``i`` set means row ``i`` is tracked (15: all four).
        t: host monotonic time of the sample, seconds (``time.monotonic()``), or
            ``None`` to let the client stamp the send time.
        device_seq: the device's own frame counter, when it has one.
        device_t: the device's own clock, seconds, when it has one.
        sites: a tracker-set device's row names (``left_foot:imu``...), in its row
            order, when the rows are not the four slots (``proto/devices.md``, v2).
    """

    positions: F64
    orientations: F64
    valid: int = 0b1111
    t: float | None = None
    device_seq: int | None = None
    device_t: float | None = None
    sites: tuple[str, ...] | None = None


class TrackerSource(abc.ABC):
    """An async iterator of :class:`TrackerSample`; ``async with`` closes it.

    ``rate_hz`` is the nominal sample rate, when the source has one.
    """

    rate_hz: float | None = None

    @abc.abstractmethod
    def __aiter__(self) -> AsyncIterator[TrackerSample]: ...

    async def aclose(self) -> None:  # noqa: B027 - optional hook, not abstract
        """Release the device (a no-op for sources without one)."""

    async def __aenter__(self) -> TrackerSource:
        return self

    async def __aexit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        await self.aclose()
