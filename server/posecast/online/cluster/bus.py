"""The bus between posecast nodes: room presence and one pose batch per room per tick.

This module is the interface and the wire format. Backends by name, chosen once
from the config by :func:`posecast.online.cluster.auto.create_bus`:

* ``memory`` (the default, no ``redis_url``): an in-process
  :class:`~posecast.online.cluster.memory.MemoryBroker`.
  ``posecast serve`` gives it a broker of its own, so it is one embedded node with
  nothing to talk to; tests hand several hubs one broker to run many nodes in one
  process, without sockets.
* ``local`` (``--workers N``, N > 1, no ``redis_url``):
  :class:`~posecast.online.cluster.local.LocalBus`, the node's worker processes
  through the supervisor's :class:`~posecast.online.cluster.relay.Relay` (a
  Unix-domain socket).
* ``redis`` (``--redis URL``): :class:`~posecast.online.cluster.redis_bus.RedisBus`, Redis
  pub/sub for announcements and pose batches, Redis hashes with heartbeats for the
  authoritative member lists. ``docs/scale-out.md`` has the design.

The hub drives a bus with plain, non-blocking calls (:meth:`Bus.watch`,
:meth:`Bus.joined`, :meth:`Bus.left`, :meth:`Bus.publish`); the bus calls back into
a :class:`BusSink` (the hub) with what other nodes did, then calls :attr:`Bus.after`
(the shell wakes the writers). What the bus carries is :class:`BusMessage`, encoded
once by :func:`encode_message` (msgpack).
"""

from __future__ import annotations

import heapq
import os
import secrets
import socket
from collections.abc import Callable, Collection, Mapping, Sequence
from dataclasses import dataclass
from typing import Any, Protocol

import msgpack

from posecast.online.protocol.pose_out import PoseOut

# 2: a tick's poses are PoseOut rows (quantised, with their scale), not v1 messages.
BUS_VERSION = 2


class BusSink(Protocol):
    """What a bus reports to (the hub). ``node`` is always another node's id."""

    def remote_join(self, room: str, player: str, name: str, node: str, now: float) -> None: ...

    def remote_leave(self, room: str, player: str, node: str, now: float) -> None: ...

    def remote_tick(
        self,
        room: str,
        node: str,
        poses: Sequence[PoseOut],
        events: Sequence[bytes],
        now: float,
    ) -> None: ...

    def remote_snapshot(
        self,
        room: str,
        live: Mapping[str, tuple[str, str]],
        issued_at: float,
        now: float,
        keep: bool = False,
        replaced: Collection[str] = (),
    ) -> None:
        """``room``'s members on other nodes as read at ``issued_at``. ``replaced``: local
        players of ``room`` that ``live`` lists on another node, read after this node's
        own entry for them was written (a takeover whose join could not cross)."""
        ...

    def remote_lost(self, now: float) -> None: ...

    def remote_burn(self, jti: str, exp: int, now: float) -> None:
        """Another node ended a session with ``bye`` or a kick: refuse its token here too."""
        ...

    def local_rooms(self) -> Mapping[str, Mapping[str, str]]:
        """Every room with a local audience -> its local players (id -> name)."""
        ...


@dataclass(frozen=True)
class BusMessage:
    """One message on a room's channel (``kind``: ``tick``, the poses and stale/active
    presence of one node's players in one tick; ``join``; ``leave``) or on the
    cluster's control channel (``burn``: a token id ``player`` and its expiry ``exp``)."""

    kind: str
    node: str
    player: str = ""
    name: str = ""
    poses: tuple[PoseOut, ...] = ()  # each stamped with the sending node's clock
    events: tuple[bytes, ...] = ()  # encoded presence messages
    exp: int = 0  # burn: Unix time the token expires


def encode_message(m: BusMessage) -> bytes:
    body: dict[str, Any] = {"v": BUS_VERSION, "k": m.kind, "n": m.node}
    if m.kind == "tick":
        body["p"] = [p.bus_row() for p in m.poses]
        if m.events:
            body["e"] = list(m.events)
    else:
        body["p"] = m.player
        if m.kind == "join":
            body["m"] = m.name
        elif m.kind == "burn":
            body["x"] = m.exp
    out: bytes = msgpack.packb(body, use_bin_type=True)
    return out


def decode_message(data: bytes) -> BusMessage | None:
    """The message, or ``None`` for anything this version does not understand (a
    newer node's message is skipped, not fatal: rolling upgrades)."""
    try:
        body = msgpack.unpackb(data, raw=False)
        if not isinstance(body, dict) or body.get("v") != BUS_VERSION:
            return None
        kind, node = str(body["k"]), str(body["n"])
        if kind == "tick":
            # Poses are PoseOut rows, checked field by field; events are encoded wire
            # messages: bytes, nothing else (an int here once made bytes(d) allocate d
            # zero bytes).
            rows, events = body["p"], body.get("e", [])
            if not isinstance(rows, list) or not isinstance(events, list):
                return None
            if not all(isinstance(e, bytes) for e in events):
                return None
            poses = PoseOut.from_bus_rows(rows)
            if poses is None:
                return None
            return BusMessage(kind, node, poses=poses, events=tuple(events))
        if kind in ("join", "leave"):
            return BusMessage(kind, node, str(body["p"]), str(body.get("m", "")))
        if kind == "burn":
            exp = body["x"]
            if type(exp) is not int:
                return None
            return BusMessage(kind, node, str(body["p"]), exp=exp)
    except (ValueError, KeyError, TypeError, OverflowError, msgpack.UnpackException):
        pass
    return None


def deliver(sink: BusSink, room: str, m: BusMessage, now: float) -> None:
    """Hand one decoded message from another node to ``sink``."""
    if m.kind == "tick":
        sink.remote_tick(room, m.node, m.poses, m.events, now)
    elif m.kind == "join":
        sink.remote_join(room, m.player, m.name, m.node, now)
    elif m.kind == "leave":
        sink.remote_leave(room, m.player, m.node, now)
    elif m.kind == "burn":
        sink.remote_burn(m.player, m.exp, now)


def default_node_id() -> str:
    host = "".join(c if c.isalnum() or c in "_.-" else "-" for c in socket.gethostname())
    return f"{host[:40] or 'node'}-{os.getpid()}-{secrets.token_hex(3)}"


class Burns:
    """Burned token ids and their expiry (Unix s), bounded like the replay guard: the
    expired are forgotten (``leeway_s`` after their ``exp``, as tokens are verified),
    and past ``capacity`` the one expiring soonest."""

    def __init__(self, capacity: int, leeway_s: float = 0.0) -> None:
        self.capacity = capacity
        self.leeway_s = leeway_s
        self._exp: dict[str, int] = {}
        self._heap: list[tuple[int, str]] = []

    def add(self, jti: str, exp: int, wall: float) -> None:
        self._purge(wall)
        if jti in self._exp or exp + self.leeway_s <= wall:
            return
        while len(self._exp) >= max(self.capacity, 1):
            self._exp.pop(heapq.heappop(self._heap)[1], None)
        self._exp[jti] = exp
        heapq.heappush(self._heap, (exp, jti))

    def live(self, wall: float) -> dict[str, int]:
        self._purge(wall)
        return dict(self._exp)

    def _purge(self, wall: float) -> None:
        while self._heap and self._heap[0][0] + self.leeway_s <= wall:
            self._exp.pop(heapq.heappop(self._heap)[1], None)


class Bus:
    """The interface every backend implements; also the no-op base."""

    # What /readyz says while the bus is down (never the cause: it may name hosts).
    unavailable = "bus unavailable"

    def __init__(self, node: str) -> None:
        self.node = node
        self.sink: BusSink | None = None
        self.after: Callable[[], None] = lambda: None  # called after delivering to the sink

    def attach(self, sink: BusSink) -> None:
        self.sink = sink

    @property
    def healthy(self) -> bool:
        """Cross-node traffic flows (``/readyz`` reports it)."""
        return True

    @property
    def status(self) -> str:
        return "ok"

    async def start(self) -> None:
        """Begin (re)connecting in the background; never waits for a remote store."""

    async def stop(self) -> None:
        """Flush announcements already made (the shutdown's leaves), then disconnect."""

    def watch(self, room: str) -> None:
        """This node now has a local audience in ``room``: receive it."""

    def unwatch(self, room: str) -> None:
        """No local audience is left in ``room``: stop receiving it."""

    def joined(self, room: str, player: str, name: str) -> None:
        """A local player joined ``room``."""

    def left(self, room: str, player: str) -> None:
        """A local player left ``room``."""

    def publish(self, room: str, poses: list[PoseOut], events: list[bytes]) -> None:
        """This tick's poses (and stale/active presence) of ``room``'s local players."""

    def burned(self, jti: str, exp: int) -> None:
        """A session ended with ``bye`` or a kick: its token id is burned everywhere."""
