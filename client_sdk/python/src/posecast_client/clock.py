"""Clock sync from ``ping``/``pong`` (NTP-style). Pure: the caller passes every time.

For one exchange, with ``t0`` the client time the ping left, ``t1``/``t2`` the server
times it arrived/the pong left, and ``t3`` the client time the pong arrived::

    offset = ((t1 - t0) + (t2 - t3)) / 2      server_time ~ client_time + offset
    rtt    = (t3 - t0) - (t2 - t1)

An exchange's offset is wrong by at most half the asymmetry of its two legs, which
is at most ``rtt / 2``; so of the last few samples the one with the smallest rtt is
the one to trust (the spec's advice, and NTP's clock filter).

That estimate steps whenever the best sample leaves the window or a better one
arrives (by up to tens of ms on a jittery link). Rendering at ``to_server(now)``
would move every remote avatar by velocity x step, so :meth:`ClockSync.display_time`
gives a display clock that slews instead, as NTP's clock discipline does: its
offset moves toward the estimate by at most ``slew_rate`` seconds per second of
client time (0.5 %: 5 ms a second, so the shown time always advances, at 0.995 to
1.005 of real speed) and steps to it only when the two differ by more than
``snap_s`` (0.1 s: the first pong, a reconnect after :meth:`ClockSync.reset`, a
restarted server).
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
        slew_rate: how fast :meth:`display_time`'s offset may move toward the
            estimate, seconds per second of client time (0.005).
        snap_s: a difference beyond which the display offset steps to the estimate
            at once (0.1 s).
    """

    window: int = 8
    slew_rate: float = 0.005
    snap_s: float = 0.1
    _samples: deque[ClockSample] = field(default_factory=deque)
    _shown_s: float | None = field(default=None, init=False, repr=False)  # display offset
    _shown_at: float | None = field(default=None, init=False, repr=False)  # its latest time

    def __post_init__(self) -> None:
        if not 0.0 <= self.slew_rate < 1.0:  # at 1 or more the shown time could stop
            raise ValueError("slew_rate must be in [0, 1)")
        if not self.snap_s >= 0.0:
            raise ValueError("snap_s must be >= 0")

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
        """Forget every sample (after a reconnect the server may be another process),
        and the display clock's offset: the next :meth:`display_time` after a pong
        starts on the new estimate."""
        self._samples.clear()
        self._shown_s = None
        self._shown_at = None

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

    def display_time(self, client_t: float) -> float:
        """The server time to render at client time ``client_t``: the display clock.

        ``client_t`` plus an offset that follows :attr:`offset_s` without jumping: it
        moves toward the estimate by at most ``slew_rate`` times the client time since
        the last call, and steps to it when the two differ by more than ``snap_s``
        (and on the first call with an estimate, after a pong or a :meth:`reset`).
        Between two calls ``dt`` apart the result so advances by between
        ``(1 - slew_rate) * dt`` and ``(1 + slew_rate) * dt``. Sample the interpolator
        here, not at :meth:`to_server`, whose steps move each avatar by velocity x step.

        Pass non-decreasing client times (one monotonic clock). An earlier time slews
        nothing (a snap still applies): it is shown with the current display offset, so
        the result goes back as far as the time did, and the next slew is counted from
        the latest time given. Before the first pong it returns ``client_t``, as
        :meth:`to_server` does.
        """
        estimate = self.offset_s
        if estimate is None:
            return client_t
        shown, last = self._shown_s, self._shown_at
        if shown is None or last is None or abs(estimate - shown) > self.snap_s:
            shown = estimate  # the first frame, a reset, or a difference too big to slew
        elif client_t > last:
            step = self.slew_rate * (client_t - last)
            shown += min(max(estimate - shown, -step), step)
        self._shown_s = shown
        self._shown_at = client_t if last is None else max(last, client_t)
        return client_t + shown

    @property
    def display_offset_s(self) -> float | None:
        """The display clock's offset as of the last :meth:`display_time` (``None``
        before it ran with an estimate, and after :meth:`reset`)."""
        return self._shown_s
