"""When a received pose is first on screen, and how far joints jump between display
frames (pure: the caller passes every time; nothing here reads a clock).

A receiver's display loop samples its SDK interpolator each frame, at client time
``now``, and gets back, per remote player, the pose shown and the server time it
shows (``InterpolatedPose.t``: the query time minus the interpolator's render delay,
whatever sets that delay). A pose with server time ``t`` received at ``r`` is
**displayed** at the first display frame at or after ``r`` whose shown time reaches
``t``: from then on the avatar stands at (or past) that pose. A pose that arrives
after the shown time has passed it (late: the interpolator was extrapolating) is
displayed at the first frame after its arrival.

Only the public sampling API is read (shown time and positions per player), so the
measure holds for a fixed render delay and for an adaptive one alike.
"""

from __future__ import annotations

import bisect
from collections.abc import Iterator, Mapping
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

F64 = NDArray[np.float64]


@dataclass(frozen=True, slots=True)
class Displayed:
    """One pose of ``sender`` (its source frame ``seq``, server time ``t``), received
    at client time ``received`` and first displayed at client time ``shown``."""

    sender: str
    seq: int
    t: float
    received: float
    shown: float


@dataclass(frozen=True, slots=True)
class _Waiting:
    t: float
    seq: int
    received: float


@dataclass
class DisplayWatch:
    """The poses one receiver got and has not displayed yet, per sender (sorted by
    ``t``); :meth:`frame` hands out those a display frame shows."""

    _waiting: dict[str, list[_Waiting]] = field(default_factory=dict)

    def received(self, sender: str, seq: int, t: float, at: float) -> None:
        """A pose of ``sender`` with server time ``t`` arrived at client time ``at``."""
        waiting = self._waiting.setdefault(sender, [])
        bisect.insort(waiting, _Waiting(t, seq, at), key=lambda w: w.t)

    def frame(self, now: float, shown_t: Mapping[str, float]) -> list[Displayed]:
        """The display frame at client time ``now`` showed each sender at server time
        ``shown_t[sender]``: the poses it displays for the first time."""
        out: list[Displayed] = []
        for sender, t in shown_t.items():
            waiting = self._waiting.get(sender)
            if not waiting:
                continue
            k = bisect.bisect_right(waiting, t, key=lambda w: w.t)
            out.extend(Displayed(sender, w.seq, w.t, w.received, now) for w in waiting[:k])
            del waiting[:k]
        return out

    def forget(self, sender: str) -> None:
        """``sender`` left: its waiting poses will never be displayed."""
        self._waiting.pop(sender, None)

    def waiting(self) -> Iterator[tuple[str, int, float, float]]:
        """``(sender, seq, t, received)`` of every pose not displayed yet."""
        for sender, waiting in self._waiting.items():
            for w in waiting:
                yield sender, w.seq, w.t, w.received


@dataclass
class JumpMeter:
    """The largest joint displacement between consecutive display frames, per sender,
    at a nominal display rate ``display_hz``.

    A frame that came late (the display loop held up: more than one period after the
    last) shows more motion through no fault of the stream; its displacement is scaled
    to one period (``d * period / dt``), so only what the stream did shows: a snap, a
    correction, a stall caught up. A frame on time or early is taken as it is.
    """

    display_hz: float
    _last: dict[str, tuple[float, F64]] = field(default_factory=dict)
    jumps_m: list[float] = field(default_factory=list)

    def frame(self, now: float, positions: Mapping[str, F64], *, record: bool = True) -> None:
        """The frame at client time ``now`` showed each sender's joints at
        ``positions[sender]`` ``(J, 3)`` metres; ``record=False`` updates the last
        frame without keeping the jumps (outside the measured window). The senders
        seen before are measured together, one array operation per shape."""
        period = 1.0 / self.display_hz
        groups: dict[tuple[int, ...], list[tuple[float, F64, F64]]] = {}
        for sender, pos in positions.items():
            last = self._last.get(sender)
            self._last[sender] = (now, pos)
            if last is None or not record or now - last[0] <= 0.0:
                continue
            groups.setdefault(pos.shape, []).append((now - last[0], pos, last[1]))
        for group in groups.values():
            dt = np.array([g[0] for g in group])  # (S,)
            moved = np.stack([g[1] for g in group]) - np.stack([g[2] for g in group])  # (S, J, 3)
            d = np.sqrt((moved * moved).sum(-1)).max(-1)  # (S,) the largest joint's move
            self.jumps_m.extend((d * np.minimum(1.0, period / dt)).tolist())

    def forget(self, sender: str) -> None:
        self._last.pop(sender, None)
