"""The hub (pure): the one object the asyncio shell talks to, built from three parts.

Data path through the hub::

    bytes --> Admission (session state machine, joins, endings, limits)
                 frames, settings --> EngineInbox --take_tick_input()--> engine thread
    TickOutput --deliver()--> Router --> each audience's Outbox, and the bus per room
    bus (other nodes' joins, leaves, batches) --> ClusterSink --> Router

* :class:`~posecast.online.core.admission.Admission`: connections, messages, joins,
  takeovers, refusals, timeouts, shutdown;
* :class:`~posecast.online.core.routing.Router`: a tick's poses and presence to the
  rooms' audiences and one batch per room to the bus;
* :class:`~posecast.online.core.cluster_sink.ClusterSink`: what the bus reports
  (the :class:`~posecast.online.cluster.bus.BusSink` side).

They share one :class:`~posecast.online.core.connections.Connections` table and one
:class:`~posecast.online.core.rooms.Rooms`. The hub decides, the shell only moves
bytes: after each call it wakes the writers in :meth:`Hub.pop_dirty` and aborts the
sockets in :meth:`Hub.pop_aborts`. Nothing here blocks, reads a clock or imports an
inference library; ``now`` everywhere is server time (monotonic seconds, what
``pose.t`` carries).
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from posecast.errors import ProtocolError
from posecast.online.auth.keys import KeySet
from posecast.online.auth.tokens import ReplayGuard, Verifier
from posecast.online.cluster.bus import Bus
from posecast.online.cluster.memory import MemoryBus
from posecast.online.config import ServerConfig
from posecast.online.core.admission import Admission
from posecast.online.core.cluster_sink import ClusterSink
from posecast.online.core.connections import Connections
from posecast.online.core.outbox import Outbox
from posecast.online.core.remote import RemoteRooms
from posecast.online.core.rooms import Rooms
from posecast.online.core.routing import Router
from posecast.online.core.session import Phase
from posecast.online.core.tick import EngineInbox, TickInput, TickOutput

if TYPE_CHECKING:
    from posecast.online.metrics import Metrics


class Hub:
    def __init__(
        self,
        cfg: ServerConfig,
        metrics: Metrics,
        wall_offset_s: float = 0.0,
        bus: Bus | None = None,
        keys: KeySet | None = None,
    ) -> None:
        """``wall_offset_s`` turns server time into Unix time for token expiry.
        Without a ``bus`` the hub is one embedded node. ``keys``: the token key set
        (default: ``cfg.key_set()``); :meth:`reload_keys` swaps it."""
        self.cfg = cfg
        self.metrics = metrics
        self.rooms = Rooms(cfg.max_players_per_room, cfg.max_watchers_per_room, cfg.max_rooms)
        self.remote = RemoteRooms()
        self.connections = Connections()
        self.inbox = EngineInbox(cfg.frame_queue)
        self.bus = bus or MemoryBus(clock=lambda: 0.0)
        replay = ReplayGuard(cfg.replay_cache, cfg.token_leeway_s)
        self.verifier = Verifier(keys if keys is not None else cfg.key_set(), cfg.token_leeway_s)
        self.router = Router(self.connections, self.rooms, self.remote, self.bus, metrics)
        self.sink = ClusterSink(
            self.connections, self.rooms, self.remote, self.router, replay, self.bus, metrics,
            wall_offset_s=wall_offset_s,
            end=lambda c, now, final: self.admission.end(c, now, final=final),
        )  # fmt: skip
        self.admission = Admission(
            cfg, metrics, self.connections, self.rooms, self.remote, self.router, self.inbox,
            replay, self.verifier, self.bus, wall_offset_s=wall_offset_s,
            changed=self.sink.refresh,
        )  # fmt: skip
        self.bus.attach(self.sink)

    # --- the shell's calls ---------------------------------------------------------------

    def reload_keys(self, keys: KeySet) -> None:
        """From the next ``hello`` on, tokens are checked with ``keys``. Joined
        sessions stay: a token is checked once, at ``hello``."""
        self.verifier.keys = keys

    def admits(self, ip: str, now: float) -> bool:
        return self.admission.admits(ip, now)

    def connect(self, ip: str, now: float, version: int = 1) -> int:
        return self.admission.connect(ip, now, version)

    def receive(self, conn: int, data: bytes | str, now: float) -> None:
        self.admission.receive(conn, data, now)

    def disconnect(self, conn: int, now: float) -> None:
        self.admission.disconnect(conn, now)

    def refused_by_transport(self, conn: int, exc: ProtocolError, now: float) -> None:
        self.admission.refused_by_transport(conn, exc, now)

    def flooded(self, conn: int, now: float) -> None:
        self.admission.flooded(conn, now)

    def joined(self, conn: int) -> bool:
        """Whether ``conn``'s ``hello`` has been admitted (and it has not ended)."""
        c = self.connections.get(conn)
        return c is not None and c.session.phase is Phase.JOINED

    def check_timeouts(self, now: float) -> None:
        self.admission.check_timeouts(now)

    def shutdown(self, now: float) -> None:
        self.admission.shutdown(now)

    def outbox(self, conn: int) -> Outbox | None:
        c = self.connections.get(conn)
        return None if c is None else c.outbox

    def pop_dirty(self) -> set[int]:
        return self.connections.pop_dirty()

    def pop_aborts(self) -> set[int]:
        return self.connections.pop_aborts()

    # --- the tick ------------------------------------------------------------------------

    def take_tick_input(self) -> TickInput:
        inp = self.inbox.take()
        if inp.drained:
            self.metrics.frames_dropped.labels("superseded").inc(inp.drained)
        inp.horizons = self.router.horizons()
        return inp

    def deliver(self, out: TickOutput, now: float) -> None:
        self.router.deliver(out, now)
