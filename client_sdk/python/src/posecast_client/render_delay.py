"""The adaptive render delay of a jitter buffer. Pure: times go in, a delay comes out.

A buffer shows ``tau = time - delay`` (``posecast_client.interp``). A display frame at
``time`` interpolates when the pose after ``tau`` has arrived by then. For a pose
``b`` whose predecessor on the server's timeline is ``a``, every frame with ``tau`` in
``[a.t, b.t)`` needs ``b``; the one at ``tau = a.t`` needs it soonest. So ``b``'s
**need** is ``seen_b - a.t``: the smallest delay at which every frame between ``a`` and
``b`` interpolates. It folds in the pose interval, a lost pose before ``b`` (the
interval doubles) and ``b``'s lateness (network, queues, clock error) alike.

``seen_b`` is the first query time at or after ``b`` was pushed, not the moment its
bytes came in: a pose that arrives between two frames is of use from the next one,
so this is the arrival the display experiences, on the query clock (the display
clock), with nothing for the caller to pass. Poses seen at a query that follows the
previous one by more than ``gap_s`` (or at the first query, or at an earlier time
than one already queried) count no need: they may have waited for the display, not
for the network (:meth:`RenderDelay.measures`).

:class:`RenderDelay` keeps the needs of the last ``window`` poses in arrival order
and, beside them, sorted (an insertion and a removal per pose: no sort per frame, no
allocation), and aims at::

    target = clamp(needs[ceil(quantile * n) - 1] + margin_s, min_s, max_s)

the nearest-rank ``quantile`` (0.99) of the ``n`` needs kept: the smallest delay at
which 99 % of the recent pose intervals interpolate from start to end, so at least
99 % of the frames do. The delay moves toward the target by at most ``slew`` times the
query time that passed (0.05: 50 ms per second), so the shown time ``tau`` runs at
``1 - slew`` to ``1 + slew`` of real speed and never goes back or jumps. A query at an
earlier time moves nothing. Before the first need, the delay stays at its start.

The same rules run in the TypeScript and C# SDKs, pinned by
``proto/vectors/sdk/delay.json``.
"""

from __future__ import annotations

import bisect
import math


def nearest_rank(sorted_values: list[float], quantile: float) -> float:
    """The nearest-rank ``quantile`` of ascending, non-empty ``sorted_values``."""
    n = len(sorted_values)
    return sorted_values[min(n - 1, max(0, math.ceil(quantile * n) - 1))]


class RenderDelay:
    """One buffer's render delay (see the module docstring).

    Args:
        start_s: the delay before the first need is known, seconds (clamped to the
            bounds).
        min_s, max_s: the bounds of the target, seconds.
        quantile: the share of recent pose intervals that should interpolate whole.
        window: needs kept (the last ``window`` poses).
        margin_s: added to the quantile, seconds.
        slew: the largest change of the delay per second of query time.
    """

    def __init__(
        self,
        *,
        start_s: float,
        min_s: float,
        max_s: float,
        quantile: float,
        window: int,
        margin_s: float,
        slew: float,
    ) -> None:
        self.start_s = min(max(start_s, min_s), max_s)
        self.min_s, self.max_s = min_s, max_s
        self.quantile, self.window = quantile, window
        self.margin_s, self.slew = margin_s, slew
        self._ring = [0.0] * window  # needs in arrival order; _next is the oldest when full
        self._count = 0
        self._next = 0
        self._sorted: list[float] = []  # the same needs, ascending
        self.delay_s = self.start_s
        self._time: float | None = None  # the latest query time

    @property
    def samples(self) -> int:
        """Needs kept now."""
        return self._count

    def measures(self, time: float, gap_s: float) -> bool:
        """Whether poses first seen at query ``time`` tell their arrival: a query at
        most ``gap_s`` after the latest one (not the first, not an earlier time)."""
        return self._time is not None and 0.0 <= time - self._time <= gap_s

    @property
    def target_s(self) -> float | None:
        """The delay aimed at (``None`` before the first need)."""
        if not self._sorted:
            return None
        q = nearest_rank(self._sorted, self.quantile)
        return min(max(q + self.margin_s, self.min_s), self.max_s)

    def observe(self, need_s: float) -> None:
        """Keep one pose's need (``seen - predecessor's t``), forgetting the oldest
        beyond ``window``."""
        if self._count == self.window:
            old = self._ring[self._next]
            del self._sorted[bisect.bisect_left(self._sorted, old)]
        else:
            self._count += 1
        self._ring[self._next] = need_s
        self._next = (self._next + 1) % self.window
        bisect.insort(self._sorted, need_s)

    def advance(self, time: float) -> float:
        """Move the delay toward the target for the query time ``time``; the delay."""
        target = self.target_s
        if self._time is not None and time > self._time and target is not None:
            step = self.slew * (time - self._time)
            if abs(target - self.delay_s) <= step:
                self.delay_s = target
            else:
                self.delay_s += step if target > self.delay_s else -step
        if self._time is None or time > self._time:
            self._time = time
        return self.delay_s

    def reset(self) -> None:
        """Forget every need and go back to the start delay."""
        self._count = self._next = 0
        self._sorted.clear()
        self.delay_s = self.start_s
        self._time = None
