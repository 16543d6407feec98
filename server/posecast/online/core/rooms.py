"""The room registry (pure): who plays in which room and who watches it.

Every connection has a server-unique id: the ``player`` claim of its token
(spectators and backends have one too). A *player* belongs to exactly one room and
is an avatar in it; a *watcher* (spectator or backend) receives one or more rooms
and is no avatar. A room's *audience* is its players plus its watchers: everyone
that receives its poses and presence. Nobody is ever in the audience of a room they
did not join or watch, which is what keeps rooms apart.

A room exists while anyone plays in or watches it. Limits: players per room, watchers
per room, rooms per server; breaking one raises ROOM_FULL.
"""

from __future__ import annotations

from dataclasses import dataclass, field

from posecast.errors import RoomFullError
from posecast.online.protocol.messages import Member


@dataclass
class Room:
    name: str
    players: dict[str, str] = field(default_factory=dict)  # player id -> display name
    watchers: set[str] = field(default_factory=set)
    _audience: tuple[str, ...] | None = None

    @property
    def audience(self) -> tuple[str, ...]:
        """Everyone who receives this room (cached; rebuilt after each change)."""
        if self._audience is None:
            self._audience = (*self.players, *sorted(self.watchers))
        return self._audience

    def members(self) -> tuple[Member, ...]:
        return tuple(Member(p, n) for p, n in self.players.items())

    @property
    def empty(self) -> bool:
        return not self.players and not self.watchers


@dataclass
class Rooms:
    max_players: int
    max_watchers: int
    max_rooms: int
    rooms: dict[str, Room] = field(default_factory=dict)
    _player_room: dict[str, str] = field(default_factory=dict)
    _watching: dict[str, tuple[str, ...]] = field(default_factory=dict)

    def check_join(
        self, room: str, watch: tuple[str, ...] = (), *, as_player: bool, rejoining: str = ""
    ) -> None:
        """Raise ROOM_FULL if joining ``room`` (plus watching ``watch``) would break a limit;
        ``rejoining``: a player of ``room`` joining it again, whose seat is its own."""
        wanted = {room, *watch}
        new_rooms = len(wanted - self.rooms.keys())
        if new_rooms and len(self.rooms) + new_rooms > self.max_rooms:
            raise RoomFullError(f"this server already has {self.max_rooms} rooms open")
        r = self.rooms.get(room)
        seated = r is not None and rejoining in r.players
        if as_player and r is not None and len(r.players) - seated >= self.max_players:
            raise RoomFullError(f"room {room!r} has {self.max_players} players", field="room")
        if not as_player:
            for name in wanted:
                w = self.rooms.get(name)
                if w is not None and len(w.watchers) >= self.max_watchers:
                    raise RoomFullError(f"room {name!r} has too many watchers", field="room")

    def add_player(self, room: str, player: str, name: str) -> Room:
        self.check_join(room, as_player=True)
        r = self.rooms.setdefault(room, Room(room))
        r.players[player] = name
        r._audience = None
        self._player_room[player] = room
        return r

    def add_watcher(self, rooms: tuple[str, ...], watcher: str) -> None:
        self.check_join(rooms[0], rooms[1:], as_player=False)
        for name in rooms:
            r = self.rooms.setdefault(name, Room(name))
            r.watchers.add(watcher)
            r._audience = None
        self._watching[watcher] = rooms

    def remove(self, who: str) -> str | None:
        """Take ``who`` out of every room; returns the room it played in, if any."""
        played = self._player_room.pop(who, None)
        if played is not None:
            r = self.rooms[played]
            del r.players[who]
            r._audience = None
            self._drop_if_empty(played)
        for name in self._watching.pop(who, ()):
            w = self.rooms.get(name)
            if w is not None:
                w.watchers.discard(who)
                w._audience = None
                self._drop_if_empty(name)
        return played

    def room_of(self, player: str) -> str | None:
        return self._player_room.get(player)

    def name_of(self, player: str) -> str:
        room = self._player_room.get(player)
        return "" if room is None else self.rooms[room].players[player]

    def audience(self, room: str) -> tuple[str, ...]:
        r = self.rooms.get(room)
        return () if r is None else r.audience

    def members(self, room: str) -> tuple[Member, ...]:
        r = self.rooms.get(room)
        return () if r is None else r.members()

    @property
    def player_count(self) -> int:
        return len(self._player_room)

    def _drop_if_empty(self, room: str) -> None:
        if self.rooms[room].empty:
            del self.rooms[room]
