"""Per-client clock offset and drift, from one-way samples (pure).

Every frame carries the client's send time ``t`` and every ping its ``t0``; the
server stamps its own receive time. ``server - client`` is the clock offset plus the
one-way network delay. Delay only ever adds, so the minimum over a window is the
best offset estimate (the sample that met the least queueing). Drift is the slope
of those windowed minima over time, in parts per million: a client clock running
50 ppm fast gains 3 ms a minute, which shows up as late-looking frames.

:class:`NodeClocks` does the same for other nodes' server clocks: a pose another
node computed carries that node's monotonic ``t``, which is this node's clock only
when both run on one host. Its clients interpolate on this node's clock, so the
pose's ``t`` is moved onto it before it goes out.
"""

from __future__ import annotations

from collections import deque
from collections.abc import Collection
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
        current = self.offset_s
        if current is not None and offset < current - JUMP_S:
            # Delay only adds to an offset: one this far below was a client clock set
            # ahead. A new epoch, no drift fitted across it (a clock set back shows as
            # frame times going back: Session restarts the estimator for those).
            self.restart()
        self.samples += 1
        if self._window_start is None:
            self._window_start = server_t
        if server_t - self._window_start >= self.window_s:
            self._close_window()
            self._window_start = server_t
        self._window_min = min(self._window_min, offset)

    def restart(self) -> None:
        """Forget every sample (the client's clock jumped)."""
        self._window_start, self._window_min = None, float("inf")
        self._minima.clear()

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


JUMP_S = 1.0  # a client clock that moves this much against the server's: it jumped
DRIFT_CAP_PPM = 1e4  # a drift past this is a broken clock, not drift: reported as the cap


@dataclass
class FrameTimes:
    """A player's frame times (``frame.t``, client clock) judged on the server's clock,
    for the frame rate limit: a player is judged by when it says it sampled each frame,
    not by when the frame reached the event loop, so frames that queued in the kernel
    while the server was busy, and arrive together, are no burst of the player's.

    The judged time of a frame is ``t + base``, ``base`` the least ``server - client``
    offset seen (the offset plus the least delay): never after the frame's arrival,
    never before the previous frame's judged time. So a clock that runs ahead, jumps
    or lies gains nothing over judging by arrival: the judged times of a connection
    advance no faster than the server's clock, and a rate limit on them allows no more
    than one on arrival times.

    :meth:`judge` also says what is odd about ``t`` (``proto/README.md``, Time):
    ``"repeat"`` (the previous frame's ``t`` again), ``"backwards"`` (before it), or
    ``"jump"`` (ahead of the server's clock, or back, by more than :data:`JUMP_S`: the
    client's clock was set; the offset starts over). A frame with an odd time is
    judged on its arrival, as before; only a frame with nothing odd is a clock sample.
    """

    base: float | None = None
    last_t: float | None = None
    judged: float = float("-inf")

    def judge(self, t: float, now: float) -> tuple[float, str | None]:
        offset = now - t
        odd: str | None = None
        if self.base is None:
            self.base = offset
        elif offset < self.base - JUMP_S or (self.last_t is not None and t < self.last_t - JUMP_S):
            odd, self.base = "jump", offset
        else:
            self.base = min(self.base, offset)
            if self.last_t is not None and t <= self.last_t:
                odd = "repeat" if t == self.last_t else "backwards"
        self.last_t = t if self.last_t is None or odd == "jump" else max(self.last_t, t)
        # An odd time says nothing of when the frame was sampled: judged on arrival,
        # as a client that ignores t (always 0, say) is.
        self.judged = max(self.judged, now if odd else min(now, t + self.base))
        return self.judged, odd


RISE_S_PER_S = 1e-3  # how fast a node's offset may grow (drift, a slower path)
RESET_S = 1.0  # a sample this far above the offset: that node's clock started again
FORGET_S = 60.0  # a node silent this long is forgotten (when another one appears)
MIN_STEP_S = 1e-6  # a player's mapped time moves on at least this much a pose


@dataclass
class NodeClocks:
    """Other nodes' monotonic clocks onto this node's, one offset per node.

    The offset is the least ``now - t`` seen (offset plus the least bus delay), as
    for clients. It may rise by :data:`RISE_S_PER_S` (clock drift between hosts, a
    path that got slower for good) and starts over when a sample is above it by more
    than :data:`RESET_S` (a new epoch). A pose's local time is then about when it
    would have arrived over the quickest path: never later than it did arrive.

    One player's mapped times never go back, though the offset drops: a batch that
    waited out a slow round trip can hold another player's newer pose (a lower
    offset) and this player's older one, and a client that orders poses by ``t``
    would show the older one after the newer. A player's time is at least
    :data:`MIN_STEP_S` past its last one (until :meth:`forget` or :meth:`retain`
    drops it, or a new epoch).
    """

    _nodes: dict[str, tuple[float, float]] = field(default_factory=dict)  # offset, last
    # player -> node -> its last mapped t (by player: a join or leave touches one entry)
    _players: dict[str, dict[str, float]] = field(default_factory=dict)

    def local(self, node: str, t: float, now: float, player: str = "") -> float:
        """``t`` on ``node``'s clock, received at ``now`` on this one, as this node's
        time; never before ``player``'s last one plus :data:`MIN_STEP_S`."""
        mapped = self._map(node, t, now)
        if not player:
            return mapped
        times = self._players.setdefault(player, {})
        last = times.get(node)
        if last is not None and mapped <= last and last - mapped < RESET_S:
            mapped = last + MIN_STEP_S
        times[node] = mapped
        return mapped

    def forget(self, player: str, node: str | None = None) -> None:
        """``player`` (of ``node``, or of any node) left: its next time starts afresh."""
        if node is not None:
            self.retain(player, set(self._players.get(player, {})) - {node})
        else:
            self._players.pop(player, None)

    def retain(self, player: str, nodes: Collection[str]) -> None:
        """Keep ``player``'s times only for ``nodes`` (those that still have it in a
        room here); of any other node its next time starts afresh."""
        times = self._players.get(player)
        if times is None:
            return
        for node in [n for n in times if n not in nodes]:
            del times[node]
        if not times:
            del self._players[player]

    @property
    def guarded(self) -> int:
        """How many (node, player) last times are held."""
        return sum(map(len, self._players.values()))

    def _map(self, node: str, t: float, now: float) -> float:
        sample = now - t
        held = self._nodes.get(node)
        if held is None:
            self._forget(now)
            offset = sample
        else:
            offset = held[0] + RISE_S_PER_S * max(0.0, now - held[1])
            if sample < offset or sample - offset > RESET_S:
                offset = sample
        self._nodes[node] = (offset, now)
        return max(0.0, t + offset)

    def _forget(self, now: float) -> None:
        gone = {n for n, (_, last) in self._nodes.items() if now - last > FORGET_S}
        for node in gone:
            del self._nodes[node]
        if gone:
            for player in list(self._players):
                self.retain(player, self._players[player].keys() - gone)

    def __len__(self) -> int:
        return len(self._nodes)
