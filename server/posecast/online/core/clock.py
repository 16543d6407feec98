"""Per-client clock offset and drift, from one-way samples (pure).

Every frame carries the client's send time ``t`` and every ping its ``t0``; the
server stamps its own receive time. ``server - client`` is the clock offset plus the
one-way network delay. Delay only ever adds, so the minimum over a window is the
best offset estimate (the sample that met the least queueing). Drift is the slope
of those windowed minima over time, in parts per million: a client clock running
50 ppm fast gains 3 ms a minute, which shows up as late-looking frames.
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass, field

WINDOW_S = 2.0  # one offset estimate per window
HISTORY = 30  # windows kept for the drift fit (a minute at 2 s)


@dataclass
class ClockEstimator:
    """Feed ``(server_t, client_t)`` samples; read :attr:`offset_s` and :attr:`drift_ppm`."""

    window_s: float = WINDOW_S
    history: int = HISTORY
    _window_start: float | None = None
    _window_min: float = float("inf")
    _minima: deque[tuple[float, float]] = field(default_factory=deque)  # (server_t, offset)
    samples: int = 0

    def add(self, server_t: float, client_t: float) -> None:
        offset = server_t - client_t
        self.samples += 1
        if self._window_start is None:
            self._window_start = server_t
        if server_t - self._window_start >= self.window_s:
            self._close_window()
            self._window_start = server_t
        self._window_min = min(self._window_min, offset)

    def _close_window(self) -> None:
        if self._window_min < float("inf") and self._window_start is not None:
            self._minima.append((self._window_start, self._window_min))
            while len(self._minima) > self.history:
                self._minima.popleft()
        self._window_min = float("inf")

    @property
    def offset_s(self) -> float | None:
        """``server - client`` clock offset (plus the least one-way delay seen), seconds."""
        if self._window_min < float("inf"):
            if self._minima:
                return min(self._window_min, self._minima[-1][1])
            return self._window_min
        return self._minima[-1][1] if self._minima else None

    @property
    def drift_ppm(self) -> float | None:
        """Least-squares slope of the windowed offsets, ppm (needs 3 windows)."""
        if len(self._minima) < 3:
            return None
        ts = [t for t, _ in self._minima]
        os_ = [o for _, o in self._minima]
        t_mean = sum(ts) / len(ts)
        o_mean = sum(os_) / len(os_)
        var = sum((t - t_mean) ** 2 for t in ts)
        if var <= 0.0:
            return None
        cov = sum((t - t_mean) * (o - o_mean) for t, o in zip(ts, os_, strict=True))
        return cov / var * 1e6
