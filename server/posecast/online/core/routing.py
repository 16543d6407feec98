"""Routing (pure): a tick's poses and presence to each room's audience, and to the bus.

Poses go into each listener's latest-wins slot (:mod:`posecast.online.core.outbox`,
``docs/broadcast.md``); presence and replies are reliable, in order. A room's
audience is its local players and watchers; players on other nodes are members of
the room but reached through the bus, one message per room per tick.

The audience may mix protocol versions. Each pose is a
:class:`~posecast.online.protocol.pose_out.PoseOut`, this node's or another's (the bus
carries it quantised, with its calibration scale): a v1 client's slot gets its pose
message, encoded once for all of them; a v2 client's gets a record prepared against its own
reference (:mod:`posecast.online.core.posestream`), on the ticks its pose rate
takes, all the tick's records in one batched encoding; a v2 client that asked for a
forecast gets the pose of its horizon instead (made in the engine thread for the
horizons :meth:`Router.horizons` lists, ``docs/latency.md``). ``welcome`` and ``presence``
are specialised per client: v2 ones carry each avatar's id and skeleton, and a
``skeleton`` message follows a player's calibration to its room's v2 clients.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import TYPE_CHECKING

from posecast.online.cluster.bus import Bus
from posecast.online.core.connections import Conn, Connections
from posecast.online.core.posestream import Avatars, PoseStream, prepare
from posecast.online.core.remote import RemoteRooms
from posecast.online.core.rooms import Rooms
from posecast.online.core.tick import TickOutput
from posecast.online.protocol.codec import encode
from posecast.online.protocol.messages import Member, Message, Presence, Welcome
from posecast.online.protocol.pose_out import PoseOut
from posecast.online.protocol.records import PoseState

if TYPE_CHECKING:
    from posecast.online.metrics import Metrics


@dataclass(eq=False)
class Router:
    conns: Connections
    rooms: Rooms
    remote: RemoteRooms
    bus: Bus
    metrics: Metrics
    avatars: Avatars = field(default_factory=Avatars)
    tick: int = 0  # ticks delivered: a v2 client at 60/k Hz takes every k-th
    # The clients that asked for a forecast: listener -> (the rooms it hears, ticks).
    ahead: dict[str, tuple[tuple[str, ...], int]] = field(default_factory=dict)

    def listen_ahead(self, listener: str, rooms: tuple[str, ...], ticks: int) -> None:
        """``listener`` (hearing ``rooms``) wants poses ``ticks`` ahead (0: none)."""
        if ticks > 0:
            self.ahead[listener] = (rooms, ticks)
        else:
            self.ahead.pop(listener, None)

    def horizons(self) -> dict[str, frozenset[int]]:
        """Per local player, the forecasts (ticks) its rooms' clients asked for: what
        the engine thread computes next tick (a few distinct horizons per room at
        most: 1-6 ticks at 60 Hz). Empty, and free, when nobody asked."""
        if not self.ahead:
            return {}
        by_room: dict[str, set[int]] = {}
        for rooms, ticks in self.ahead.values():
            for room in rooms:
                by_room.setdefault(room, set()).add(ticks)
        out: dict[str, frozenset[int]] = {}
        for room, asked in by_room.items():
            r = self.rooms.rooms.get(room)
            if r is not None:
                hs = frozenset(asked)
                for player in r.players:
                    out[player] = hs
        return out

    def send(self, c: Conn, msg: Message, now: float) -> None:
        stream = c.outbox.stream
        if stream is not None:
            msg = self._v2(stream, msg)
        self.conns.send(c, encode(msg), now)

    def _v2(self, stream: PoseStream, msg: Message) -> Message:
        """``msg`` as a v2 client gets it, and what it tells that client about avatars."""
        if isinstance(msg, Welcome):
            members = tuple(self.avatars.member(m) for m in msg.members)
            for m in members:
                assert m.avatar_id is not None
                stream.announce(m.player, m.avatar_id)
            return Welcome(msg.version, msg.player, msg.session, msg.role, msg.room, msg.t,
                           msg.rate_hz, msg.lookahead_frames, members, msg.limits,
                           stream.pose_rate_hz, stream.ahead_ms or None)  # fmt: skip
        if isinstance(msg, Presence):
            if msg.event == "join":
                msg = self.avatars.presence(msg)
                assert msg.avatar_id is not None
                stream.announce(msg.player, msg.avatar_id)
            elif msg.event == "leave":
                stream.forget(msg.player)
        return msg

    def to_room(self, room: str, msg: Message, now: float, skip: str | None = None) -> None:
        if isinstance(msg, Presence):
            self.presence_to_room(room, msg, now, skip)
        else:
            self.bytes_to_room(room, encode(msg), now, skip)

    def presence_to_room(self, room: str, p: Presence, now: float, skip: str | None) -> None:
        """``p`` to ``room``'s audience, v1 and v2 each in their form (encoded once)."""
        v1: bytes | None = None
        v2: bytes | None = None
        for member in self.rooms.audience(room):
            c = self.conns.of_player(member) if member != skip else None
            if c is None:
                continue
            if p.event == "leave":  # no pose of the player after its leave
                c.outbox.drop_pose(p.player)
            stream = c.outbox.stream
            if stream is None:
                v1 = v1 or encode(p.v1())
                self.conns.send(c, v1, now)
            else:
                mine = self._v2(stream, p)  # each client's own view: announce or forget
                v2 = v2 or encode(mine)
                self.conns.send(c, v2, now)
        if p.event == "leave":
            self.release_if_gone(p.player)

    def release_if_gone(self, player: str) -> None:
        """``player``'s avatar (id, skeleton) goes, unless it is still seen here: a
        local player, or another node's in any room (one that moved between rooms may
        be announced in its new room before it leaves the old one)."""
        if self.rooms.room_of(player) is None and not self.remote.holds(player):
            self.avatars.release(player)

    def bytes_to_room(self, room: str, data: bytes, now: float, skip: str | None = None) -> None:
        for member in self.rooms.audience(room):
            if member != skip:
                self.conns.send_to_player(member, data, now)

    def pose_to_room(self, room: str, pose: PoseOut, now: float) -> int:
        """One pose to ``room``'s audience; how many older ones it superseded."""
        return self.poses_to_room(room, [pose], now)

    def poses_to_room(self, room: str, poses: list[PoseOut], now: float) -> int:
        """Poses of ``room`` to its audience (v2 records prepared in one batch)."""
        requests: list[tuple[Conn, PoseStream, PoseState]] = []
        superseded = self._route(room, poses, now, requests)
        return superseded + self._put_v2(requests, now)

    def _route(
        self,
        room: str,
        poses: list[PoseOut],
        now: float,
        requests: list[tuple[Conn, PoseStream, PoseState]],
        ahead: dict[int, dict[str, PoseOut]] | None = None,
    ) -> int:
        """``ahead``: per horizon (ticks), the forecast poses, for v2 clients that asked
        (a pose without one, another node's, goes as it is)."""
        superseded = 0
        v1: list[Conn] = []
        v2: list[tuple[Conn, PoseStream]] = []  # the v2 clients whose tick this is
        for member in self.rooms.audience(room):
            c = self.conns.of_player(member)
            if c is None:
                continue
            stream = c.outbox.stream
            if stream is None:
                v1.append(c)
            elif stream.accepts(self.tick):
                v2.append((c, stream))
        for pose in poses:
            self._rescaled(room, pose.state, now)
            if v1:
                data = pose.v1()
                for c in v1:
                    superseded += self.conns.pose_to_conn(c, pose.player, data, now)
            if ahead:
                requests.extend(
                    (c, s, ahead.get(s.ahead, {}).get(pose.player, pose).state)
                    for c, s in v2
                    if pose.player in s.known
                )
            else:
                requests.extend((c, s, pose.state) for c, s in v2 if pose.player in s.known)
        return superseded

    def _put_v2(self, requests: list[tuple[Conn, PoseStream, PoseState]], now: float) -> int:
        if not requests:
            return 0
        players = {st.player for _, _, st in requests}
        keyed = frozenset(p for p in players if self.avatars.keyframe_tick(p, self.tick))
        slots = prepare([(s, st) for _, s, st in requests], now, keyed)
        superseded = 0
        for (c, _, st), slot in zip(requests, slots, strict=True):
            if slot is not None:
                superseded += self.conns.pose_to_conn(c, st.player, slot, now)
        return superseded

    def _rescaled(self, room: str, state: PoseState, now: float) -> None:
        """A new calibration (this node's player or another node's, whose scale the bus
        carries): its skeleton reaches the room's v2 clients before the pose."""
        if self.avatars.rescale(state.player, state.scale) is not None:
            self.bytes_to_room_v2(room, encode(self.avatars.skeleton_message(state.player)), now)

    def bytes_to_room_v2(self, room: str, data: bytes, now: float) -> None:
        """A v2-only message to ``room``'s v2 audience."""
        for member in self.rooms.audience(room):
            c = self.conns.of_player(member)
            if c is not None and c.outbox.stream is not None:
                self.conns.send(c, data, now)

    def members(self, room: str) -> tuple[Member, ...]:
        return self.rooms.members(room) + self.remote.members(room)

    def deliver(self, out: TickOutput, now: float) -> None:
        """Route one tick's poses to their rooms' audiences, and stale/active presence."""
        superseded = 0
        self.tick += 1
        batches: dict[str, tuple[list[PoseOut], list[bytes]]] = {}
        requests: list[tuple[Conn, PoseStream, PoseState]] = []
        for pose in out.poses:
            room = self.rooms.room_of(pose.player)
            if room is None:
                continue  # left while the tick ran
            batches.setdefault(room, ([], []))[0].append(pose)
        for room, (room_poses, _) in batches.items():
            superseded += self._route(room, room_poses, now, requests, out.ahead)
        superseded += self._put_v2(requests, now)
        for ev in out.events:
            room = self.rooms.room_of(ev.player)
            if room is not None:
                name = self.rooms.name_of(ev.player)
                data = encode(Presence(ev.kind.value, room, ev.player, name))
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
