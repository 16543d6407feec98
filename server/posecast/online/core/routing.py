"""Routing (pure): a tick's poses and presence to each room's audience, and to the bus.

Poses go into each listener's latest-wins slot (:mod:`posecast.online.core.outbox`,
``docs/broadcast.md``); presence and replies are reliable, in order. A room's
audience is its local players and watchers; players on other nodes are members of
the room but reached through the bus, one message per room per tick.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from posecast.online.cluster.bus import Bus
from posecast.online.core.connections import Conn, Connections
from posecast.online.core.remote import RemoteRooms
from posecast.online.core.rooms import Rooms
from posecast.online.core.tick import TickOutput
from posecast.online.protocol.codec import encode
from posecast.online.protocol.messages import Member, Message, Presence

if TYPE_CHECKING:
    from posecast.online.metrics import Metrics


class Router:
    def __init__(
        self,
        conns: Connections,
        rooms: Rooms,
        remote: RemoteRooms,
        bus: Bus,
        metrics: Metrics,
    ) -> None:
        self.conns = conns
        self.rooms = rooms
        self.remote = remote
        self.bus = bus
        self.metrics = metrics

    def send(self, c: Conn, msg: Message, now: float) -> None:
        self.conns.send(c, encode(msg), now)

    def to_room(self, room: str, msg: Message, now: float, skip: str | None = None) -> None:
        self.bytes_to_room(room, encode(msg), now, skip)

    def bytes_to_room(self, room: str, data: bytes, now: float, skip: str | None = None) -> None:
        for member in self.rooms.audience(room):
            if member != skip:
                self.conns.send_to_player(member, data, now)

    def pose_to_room(self, room: str, player: str, data: bytes, now: float) -> int:
        """``player``'s pose to ``room``'s audience; how many older ones it superseded."""
        return sum(
            self.conns.pose_to_player(member, player, data, now)
            for member in self.rooms.audience(room)
        )

    def members(self, room: str) -> tuple[Member, ...]:
        return self.rooms.members(room) + self.remote.members(room)

    def deliver(self, out: TickOutput, now: float) -> None:
        """Route one tick's poses to their rooms' audiences, and stale/active presence."""
        superseded = 0
        batches: dict[str, tuple[list[tuple[str, bytes]], list[bytes]]] = {}
        for player, data in out.poses:
            room = self.rooms.room_of(player)
            if room is None:
                continue  # left while the tick ran
            batches.setdefault(room, ([], []))[0].append((player, data))
            superseded += self.pose_to_room(room, player, data, now)
        for ev in out.events:
            room = self.rooms.room_of(ev.player)
            if room is not None:
                name = self.rooms.name_of(ev.player)
                data = encode(Presence(ev.kind, room, ev.player, name))
                batches.setdefault(room, ([], []))[1].append(data)
                self.bytes_to_room(room, data, now)
        for room, (poses, events) in batches.items():
            self.bus.publish(room, poses, events)  # ONE message per room per tick
        m = self.metrics
        m.ticks.inc()
        if out.poses:
            m.poses.inc(len(out.poses))
        if superseded:
            m.poses_superseded.inc(superseded)
        m.tick_seconds.observe(out.seconds)
        m.batch_size.observe(out.batch)
        if out.transitions:
            m.transitions.inc(out.transitions)
        if out.reach_limited:
            m.reach_limited.inc(out.reach_limited)
