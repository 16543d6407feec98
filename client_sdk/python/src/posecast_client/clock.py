"""Clock sync from ``ping``/``pong`` (NTP-style). Pure: the caller passes every time.

For one exchange, with ``t0`` the client time the ping left, ``t1``/``t2`` the server
times it arrived/the pong left, and ``t3`` the client time the pong arrived::

    offset = ((t1 - t0) + (t2 - t3)) / 2      server_time ~ client_time + offset
    rtt    = (t3 - t0) - (t2 - t1)

An exchange's offset is wrong by at most half the asymmetry of its two legs, which
is at most ``rtt / 2``; so of the last few samples the one with the smallest rtt is
the one to trust (the spec's advice, and NTP's clock filter).
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass, field


@dataclass(frozen=True, slots=True)
class ClockSample:
    offset_s: float  # server minus client time
    rtt_s: float  # round trip without the server's own time
    at_s: float  # client time of the sample (t3)


@dataclass
class ClockSync:
    """Offset estimate between the client's and the server's monotonic clocks.

    Args:
        window: how many recent samples the estimate picks from (8).
    """

    window: int = 8
    _samples: deque[ClockSample] = field(default_factory=deque)

    def add(self, t0: float, t1: float, t2: float, t3: float) -> ClockSample | None:
        """Record one exchange; returns its sample (``None`` if the times are absurd)."""
        rtt = (t3 - t0) - (t2 - t1)
        if rtt < 0 or t3 < t0:  # a clock jumped, or a pong for a ping of another life
            return None
        sample = ClockSample(((t1 - t0) + (t2 - t3)) / 2.0, rtt, t3)
        self._samples.append(sample)
        while len(self._samples) > self.window:
            self._samples.popleft()
        return sample

    def reset(self) -> None:
        """Forget every sample (after a reconnect the server may be another process)."""
        self._samples.clear()

    @property
    def best(self) -> ClockSample | None:
        """The recent sample with the smallest rtt, or ``None`` before the first pong."""
        return min(self._samples, key=lambda s: s.rtt_s, default=None)

    @property
    def offset_s(self) -> float | None:
        """Server time minus client time, seconds (``None`` until a pong arrived)."""
        best = self.best
        return None if best is None else best.offset_s

    @property
    def rtt_s(self) -> float | None:
        best = self.best
        return None if best is None else best.rtt_s

    def to_server(self, client_t: float) -> float:
        """A client time on the server's clock (unchanged before the first pong)."""
        return client_t + (self.offset_s or 0.0)

    def to_client(self, server_t: float) -> float:
        """A server time (``pose.t``, ``welcome.t``) on the client's clock."""
        return server_t - (self.offset_s or 0.0)
