"""Players on other nodes (pure): this node's view of who plays in its rooms elsewhere.

A node only tracks the rooms it has a local audience in (players or watchers); for
those, every remote player is a :class:`RemoteMember` tagged with the node that
hosts it. Two sources feed the view, with no ordering between them:

* **announcements** from the bus, ``join`` and ``leave``: fast (one hop), but lost
  while the bus is down;
* **snapshots** of the room's member list read from the shared store, once per
  heartbeat: slow, authoritative, and already stripped of dead nodes' players.

A snapshot is a read issued at some time ``issued_at`` and applied later, so it may
predate an announcement that arrived in between. Two rules keep the view from
flapping: a snapshot never removes a member learnt *after* it was issued, and never
restores a member that left after it was issued (a tombstone remembers the leave).

Every call returns what changed, so the hub announces exactly those changes to the
local audience. No I/O and no clock: callers pass ``now``.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field

from posecast.online.protocol.messages import Member


@dataclass
class RemoteMember:
    node: str
    name: str
    since: float  # when this view learnt it (announcement time or snapshot issue time)


@dataclass
class RemoteRooms:
    """Remote members of each watched room, plus leave tombstones for snapshot races."""

    _rooms: dict[str, dict[str, RemoteMember]] = field(default_factory=dict)
    _left: dict[tuple[str, str], float] = field(default_factory=dict)

    def join(self, room: str, player: str, node: str, name: str, now: float) -> bool:
        """``player`` plays in ``room`` on ``node``; ``True`` if it is new to the view
        (a move between two nodes is not a new member)."""
        members = self._rooms.setdefault(room, {})
        is_new = player not in members
        members[player] = RemoteMember(node, name, now)
        self._left.pop((room, player), None)
        return is_new

    def leave(self, room: str, player: str, node: str, now: float) -> RemoteMember | None:
        """``node`` says ``player`` left ``room``; the member if that removed it.

        A leave from a node other than the one the view has for the player is stale
        (the player moved on) and changes nothing."""
        members = self._rooms.get(room, {})
        m = members.get(player)
        if m is not None and m.node != node:
            return None
        self._left[(room, player)] = now
        return members.pop(player, None)

    def snapshot(
        self, room: str, live: Mapping[str, tuple[str, str]], issued_at: float
    ) -> tuple[list[Member], list[Member]]:
        """Reconcile ``room`` with ``live`` (player -> (node, name)) as read at
        ``issued_at``; returns ``(joined, left)``."""
        members = self._rooms.setdefault(room, {})
        joined: list[Member] = []
        for player, (node, name) in live.items():
            m = members.get(player)
            if m is not None:
                if m.since < issued_at:
                    m.node = node  # the store is newer than what the view learnt
                continue
            gone_at = self._left.get((room, player))
            if gone_at is not None and gone_at >= issued_at:
                continue  # left after the read: the read is stale for this player
            members[player] = RemoteMember(node, name, issued_at)
            joined.append(Member(player, name))
        left = [
            Member(p, m.name) for p, m in members.items() if p not in live and m.since < issued_at
        ]
        for gone in left:
            del members[gone.player]
        for key in [k for k, t in self._left.items() if k[0] == room and t < issued_at]:
            del self._left[key]  # older than a read that saw the room after it
        return joined, left

    def drop_room(self, room: str) -> tuple[str, ...]:
        """No local audience left in ``room``: stop tracking it; returns the players
        it held."""
        members = self._rooms.pop(room, {})
        for key in [k for k in self._left if k[0] == room]:
            del self._left[key]
        return tuple(members)

    def get(self, room: str, player: str) -> RemoteMember | None:
        return self._rooms.get(room, {}).get(player)

    def holds(self, player: str) -> bool:
        """``player`` is a remote member of any room here."""
        return any(player in members for members in self._rooms.values())

    def nodes_of(self, player: str) -> set[str]:
        """The nodes that have ``player`` in a room here (more than one while it moves)."""
        return {m[player].node for m in self._rooms.values() if player in m}

    def members(self, room: str) -> tuple[Member, ...]:
        return tuple(Member(p, m.name) for p, m in self._rooms.get(room, {}).items())

    def count(self, room: str) -> int:
        return len(self._rooms.get(room, {}))

    @property
    def rooms(self) -> tuple[str, ...]:
        return tuple(self._rooms)

    @property
    def total(self) -> int:
        return sum(map(len, self._rooms.values()))
