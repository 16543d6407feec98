"""The cluster sink (pure): what other nodes did, as the bus reports it, into this
node's rooms (:class:`~posecast.online.cluster.bus.BusSink`).

Remote players are members of a room (``welcome``, presence, capacity) but no
audience: their poses arrive as one batch per room per tick and go to the local
audience's latest-wins slots, their ``t`` moved onto this node's clock
(:class:`~posecast.online.core.clock.NodeClocks`: nodes on other hosts have other
monotonic clocks, and clients interpolate on this one's). The sink also keeps the
bus watching exactly the rooms this node has an audience in
(:meth:`ClusterSink.refresh`), and the room gauges.
"""

from __future__ import annotations

from collections.abc import Callable, Collection, Mapping, Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

from posecast.errors import ProtocolError, ReplacedError
from posecast.online.auth.tokens import Claims, ReplayGuard
from posecast.online.cluster.bus import Bus
from posecast.online.core.clock import NodeClocks
from posecast.online.core.connections import Conn, Connections
from posecast.online.core.remote import RemoteRooms
from posecast.online.core.rooms import Rooms
from posecast.online.core.routing import Router
from posecast.online.protocol import decode
from posecast.online.protocol.messages import Error, Presence
from posecast.online.protocol.pose_out import PoseOut

if TYPE_CHECKING:
    from posecast.online.metrics import Metrics


@dataclass(eq=False)
class ClusterSink:
    conns: Connections
    rooms: Rooms
    remote: RemoteRooms
    router: Router
    replay: ReplayGuard
    bus: Bus
    metrics: Metrics
    wall_offset_s: float = field(kw_only=True)
    # end(conn, now, final) ends a local connection (admission's ending)
    end: Callable[[Conn, float, Error], None] = field(kw_only=True)
    _watched: set[str] = field(default_factory=set)  # rooms the bus delivers to this node
    clocks: NodeClocks = field(default_factory=NodeClocks)  # other nodes' clocks onto ours

    def remote_join(self, room: str, player: str, name: str, node: str, now: float) -> None:
        local = self.conns.of_player(player)
        if local is not None and local.session.role == "player":
            # The same player joined on another node (a reconnect through the balancer
            # landed elsewhere): that one wins, as a takeover does on one node.
            replaced = ReplacedError("the same player joined on another node")
            self.end(local, now, Error.from_exception(replaced))
        if room not in self._watched:
            return
        is_new = self.remote.join(room, player, node, name, now)
        self._release_clock(player)  # of the node it moved away from, if any
        if is_new:
            self.router.to_room(room, Presence("join", room, player, name), now)
            self.refresh()

    def remote_leave(self, room: str, player: str, node: str, now: float) -> None:
        gone = self.remote.leave(room, player, node, now)
        if gone is not None:
            self._release_clock(player)
        if gone is not None and self.rooms.room_of(player) != room:
            self.router.to_room(room, Presence("leave", room, player, gone.name), now)
            self.refresh()

    def _release_clock(self, player: str) -> None:
        """``player``'s time guard goes for the nodes that no longer have it in any room
        here (one moving between rooms is in both a while: a leave of the old room must
        not let its poses in the new one go back), and with its last room, entirely."""
        self.clocks.retain(player, self.remote.nodes_of(player))

    def remote_tick(
        self,
        room: str,
        node: str,
        poses: Sequence[PoseOut],
        events: Sequence[bytes],
        now: float,
    ) -> None:
        unknown = superseded = 0
        for pose in poses:
            m = self.remote.get(room, pose.player)
            if m is None or m.node != node:
                unknown += 1  # not (yet) a member here: its join or the snapshot comes first
                continue
            local = pose.at(self.clocks.local(node, pose.t, now, pose.player))
            superseded += self.router.pose_to_room(room, local, now)
        for data in events:
            if self._member_event(room, node, data):
                self.router.bytes_to_room(room, data, now)
            else:
                unknown += 1
        if unknown:
            self.metrics.bus_dropped.labels("unknown_player").inc(unknown)
        if superseded:
            self.metrics.poses_superseded.inc(superseded)

    def _member_event(self, room: str, node: str, data: bytes) -> bool:
        """``data`` is a ``stale``/``active`` presence of a player ``node`` has in
        ``room`` as this node sees it now (not one that has left meanwhile: its leave
        was announced here already, and a client would not hear of it again)."""
        try:
            ev = decode(data)
        except ProtocolError:
            return False
        if not isinstance(ev, Presence) or ev.event not in ("stale", "active") or ev.room != room:
            return False
        m = self.remote.get(room, ev.player)
        return m is not None and m.node == node

    def remote_snapshot(
        self,
        room: str,
        live: Mapping[str, tuple[str, str]],
        issued_at: float,
        now: float,
        keep: bool = False,
        replaced: Collection[str] = (),
    ) -> None:
        """Reconcile ``room``'s remote members with ``live`` (player -> (node, name)).
        ``keep``: add, never remove (a read that other nodes may not have refilled
        yet, e.g. just after Redis came back empty). ``replaced``: local players that
        another node has taken over since this node's entry for them was written (the
        bus vouches the read came after that write): their sessions end here."""
        if room not in self._watched:
            return
        r = self.rooms.rooms.get(room)
        for player in replaced:
            c = self.conns.of_player(player)
            if (
                r is not None
                and player in r.players
                and player in live
                and c is not None
                and c.session.role == "player"
            ):
                # The join there could not reach this node (a Redis outage): it wins,
                # as the join would have made it.
                gone = ReplacedError("the same player joined on another node")
                self.end(c, now, Error.from_exception(gone))
        if room not in self._watched:
            return  # that was the room's last local audience
        r = self.rooms.rooms.get(room)
        local = r.players if r is not None else {}
        others = {p: v for p, v in live.items() if p not in local}
        if keep:
            for m in self.remote.members(room):
                held = self.remote.get(room, m.player)
                if held is not None and m.player not in others:
                    others[m.player] = (held.node, m.name)
        joined, left = self.remote.snapshot(room, others, issued_at)
        for m in left:
            self._release_clock(m.player)
            if m.player not in local:  # one that moved here left the remote view only
                self.router.to_room(room, Presence("leave", room, m.player, m.name), now)
        for m in joined:
            self.router.to_room(room, Presence("join", room, m.player, m.name), now)
        if joined or left:
            self.refresh()

    def remote_lost(self, now: float) -> None:
        """The bus has been down past the node TTL: remote players count as gone."""
        for room in self.remote.rooms:
            self.remote_snapshot(room, {}, float("inf"), now)

    def remote_burn(self, jti: str, exp: int, now: float) -> None:
        self.replay.end(Claims("", "", "", 0, exp, jti), now + self.wall_offset_s)

    def local_rooms(self) -> dict[str, dict[str, str]]:
        return {name: dict(r.players) for name, r in self.rooms.rooms.items()}

    def refresh(self) -> None:
        """The gauges, and the bus watching exactly the rooms open here."""
        self.metrics.players.set(self.rooms.player_count)
        self.metrics.rooms.set(len(self.rooms.rooms))
        rooms = set(self.rooms.rooms)
        new, gone, self._watched = rooms - self._watched, self._watched - rooms, rooms
        for room in gone:
            self.bus.unwatch(room)
            for player in self.remote.drop_room(room):
                self._release_clock(player)
                self.router.release_if_gone(player)
        for room in new:
            self.bus.watch(room)  # may report the room's remote members at once
        self.metrics.remote_players.set(self.remote.total)
