"""What crosses between the hub and the engine thread each tick (pure data), and the
inbox that gathers it between ticks.

::

    sessions --frames, calibrations, selectors--> EngineInbox --take()--> TickInput
    engine thread: TickInput -> one batched step -> TickOutput --> Router.deliver

Frames wait in a short queue per player (``frame_queue``, 2 by default): each tick
the engine steps the oldest one. A client whose frames arrive near the tick boundary
(60 Hz against 60 Hz, with a millisecond of network or scheduling jitter) sends two
in one tick and none in the next; with one slot the older would be lost and the next
tick would hold: a pose missing from the stream and a hitch on every avatar that
watches. With two, both are stepped, the second one tick later; the queue drains at
the next gap. Past its depth the oldest waiting frame is superseded (latest wins,
counted as dropped). A backlog that stands (a frame still waiting after each take
for :data:`STANDING_TICKS` ticks in a row: one bunch, then frames one a tick, so
every later frame waits a tick more until one comes late) is drained: that take
supersedes the oldest waiting frame and steps the next, one frame for two seconds
of standing delay. A client that
announces more frames per second than the tick rate (``hello.rate_hz``: a 72, 90 or
120 Hz headset) would keep the queue full for good, one tick behind: it gets a queue
of one, the newest frame, as every client did before the queue. So does a client that
sends faster than the tick without saying so (a game engine streaming at its display
rate): over each second (:data:`RATE_WINDOW_TICKS`) its frames are counted, and one
whose frames came at more than :data:`FAST_FRAMES_PER_TICK` a tick for two seconds
in a row (not a 60 Hz client flushing what a stall held back) is stepped on its
newest frame from then on, the older ones superseded, until a second at 60 Hz.

A player enters the engine with its first frame (or its first calibration or
selector), not when it joins: a connection that joins and never streams (a client
still loading, or one that sends garbage and is cut off) costs the engine thread
nothing, and leaves without an engine ``remove``.
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass, field
from enum import StrEnum

from posecast.online.engine.calibration import Calibration
from posecast.online.engine.selectors import SampleSelector
from posecast.online.engine.types import EngineEvent, TrackerFrame
from posecast.online.protocol.pose_out import PoseOut
from posecast.tracking.layouts import Layout, PlayerLayout

RATE_WINDOW_TICKS = 60  # the window the arrival rate of unannounced fast clients is read over
FAST_FRAMES_PER_TICK = 1.1  # 66 Hz at a 60 Hz tick: above any 60 Hz client's jitter or drift
STANDING_TICKS = 120  # takes a backlog may stand before one drains a frame (2 s at 60 Hz)


class EngineOpKind(StrEnum):
    """What an :class:`EngineOp` does (the value is what logs show)."""

    ADD = "add"  # the player enters the engine (``seed``, ``layout``)
    REMOVE = "remove"  # the player leaves it
    SELECTOR = "selector"  # a new sample selector (``selector``)
    CALIBRATION = "calibration"  # a new calibration (``calibration``)


@dataclass(frozen=True)
class EngineOp:
    """A membership or setting change, applied in the engine thread before a step."""

    kind: EngineOpKind
    player: str
    seed: int = 0
    layout: PlayerLayout = Layout.HMD3_WAIST  # add: the player's layout (picks the batch)
    selector: SampleSelector | None = None
    calibration: Calibration | None = None


@dataclass
class TickInput:
    ops: list[EngineOp]
    frames: dict[str, TrackerFrame]  # each player's oldest waiting frame
    # The forecasts its room's clients asked for, per player: frames ahead (none: {}).
    horizons: dict[str, frozenset[int]] = field(default_factory=dict)
    drained: int = 0  # frames superseded by this take: backlogs that stood (STANDING_TICKS)


@dataclass
class TickOutput:
    poses: list[PoseOut]  # the tick's shown poses, quantised once for every way out
    events: list[EngineEvent] = field(default_factory=list)
    transitions: int = 0
    batch: int = 0  # players in the step
    seconds: float = 0.0  # wall time of the step in the engine thread
    reach_limited: int = 0  # poses sent whose head or a hand could not reach its tracker
    # Per horizon (frames) some client asked for, each player's pose forecast that far
    # ahead of its shown pose, stamped as far past the tick (v2 clients only).
    ahead: dict[int, dict[str, PoseOut]] = field(default_factory=dict)


class EngineInbox:
    """Engine ops, and each player's waiting frames, until the tick takes them."""

    def __init__(self, frame_queue: int = 2) -> None:
        self.depth = frame_queue
        self._ops: list[EngineOp] = []
        self._frames: dict[str, deque[TrackerFrame]] = {}
        self._depth: dict[str, int] = {}  # per player, when it differs from ``depth``
        self._waiting: dict[str, tuple[int, PlayerLayout]] = {}  # joined, not in the engine yet
        self._in_engine: set[str] = set()
        self._arrived: dict[str, int] = {}  # frames per player in this rate window
        self._window = 0  # ticks taken in this rate window
        self._over: set[str] = set()  # sent faster than the tick over the last window
        self._fast: set[str] = set()  # ... and the one before it
        self._standing: dict[str, int] = {}  # takes in a row that left a frame waiting

    def joined(
        self, player: str, seed: int, layout: PlayerLayout, queue: int | None = None
    ) -> None:
        """``player`` joined; it enters the engine with its first frame or setting.
        ``queue``: its frame queue's depth (default: the inbox's)."""
        self._waiting[player] = (seed, layout)
        if queue is not None:
            self._depth[player] = queue

    def frame(self, player: str, frame: TrackerFrame) -> int:
        """Queue ``frame``; how many older frames it superseded (the queue was full)."""
        self._enter(player)
        self._arrived[player] = self._arrived.get(player, 0) + 1
        queue = self._frames.setdefault(player, deque())
        depth = self._depth.get(player) or (1 if player in self._fast else self.depth)
        superseded = max(0, len(queue) - depth + 1)
        for _ in range(superseded):
            queue.popleft()
        queue.append(frame)
        return superseded

    def setting(self, op: EngineOp) -> None:
        """A selector or calibration for ``op.player``."""
        self._enter(op.player)
        self._ops.append(op)

    def left(self, player: str) -> None:
        self._waiting.pop(player, None)
        self._frames.pop(player, None)
        self._depth.pop(player, None)
        self._arrived.pop(player, None)
        self._standing.pop(player, None)
        self._fast.discard(player)
        self._over.discard(player)
        if player in self._in_engine:
            self._in_engine.discard(player)
            self._ops.append(EngineOp(EngineOpKind.REMOVE, player))

    def take(self) -> TickInput:
        self._window += 1
        if self._window >= RATE_WINDOW_TICKS:
            limit = FAST_FRAMES_PER_TICK * self._window
            over = {p for p, n in self._arrived.items() if n > limit}
            self._fast, self._over = over & self._over, over
            self._arrived.clear()
            self._window = 0
        ops, self._ops = self._ops, []
        frames = {}
        drained = 0
        for player, queue in list(self._frames.items()):
            if len(queue) > 1:  # a frame will still wait after this take
                standing = self._standing.get(player, 0) + 1
                if standing >= STANDING_TICKS:
                    queue.popleft()
                    drained += 1
                    standing = 0
                self._standing[player] = standing
            elif player in self._standing:
                del self._standing[player]
            frames[player] = queue.popleft()
            if not queue:
                del self._frames[player]
        return TickInput(ops, frames, drained=drained)

    def _enter(self, player: str) -> None:
        waiting = self._waiting.pop(player, None)
        if waiting is not None:
            seed, layout = waiting
            self._in_engine.add(player)
            self._ops.append(EngineOp(EngineOpKind.ADD, player, seed=seed, layout=layout))
