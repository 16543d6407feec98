"""Every connection's session and outbox, by connection id and by joined player (pure).

The table the hub's parts share: admission opens and ends connections here, routing
writes into their outboxes, the cluster sink looks players up. What the asyncio
shell must do afterwards is collected here too: which writers to wake
(:meth:`Connections.pop_dirty`) and which sockets to abort (:meth:`pop_aborts`).
"""

from __future__ import annotations

from dataclasses import dataclass

from posecast.online.core.outbox import Outbox
from posecast.online.core.posestream import Slot
from posecast.online.core.ratelimit import TokenBucket
from posecast.online.core.session import Session


@dataclass
class Conn:
    session: Session
    outbox: Outbox
    errors: TokenBucket  # budget of non-fatal error replies (the rest are only counted)
    replaced: bool = False  # a newer connection of the same player took its place


class Connections:
    def __init__(self) -> None:
        self.conns: dict[int, Conn] = {}
        self.by_player: dict[str, int] = {}  # connection id of each joined id
        self._next = 0
        self._dirty: set[int] = set()
        self._aborts: set[int] = set()

    def next_id(self) -> int:
        self._next += 1
        return self._next

    def get(self, conn: int) -> Conn | None:
        return self.conns.get(conn)

    def of_player(self, player: str) -> Conn | None:
        conn = self.by_player.get(player)
        return None if conn is None else self.conns.get(conn)

    def send(self, c: Conn, data: bytes, now: float) -> None:
        c.outbox.put_reliable(data, now)  # overflow: check_timeouts cuts it off
        self._dirty.add(c.session.conn)

    def send_to_player(self, player: str, data: bytes, now: float) -> None:
        c = self.of_player(player)
        if c is not None:
            self.send(c, data, now)

    def pose_to_player(self, player: str, source: str, data: bytes, now: float) -> int:
        """``source``'s pose into ``player``'s latest-wins slot; 1 when it superseded one."""
        conn = self.by_player.get(player)
        if conn is None:
            return 0
        self._dirty.add(conn)
        return self.conns[conn].outbox.put_pose(source, data, now)

    def pose_to_conn(self, c: Conn, source: str, data: bytes | Slot, now: float) -> int:
        """``source``'s pose (v1 bytes or a v2 record) into ``c``'s latest-wins slot."""
        self._dirty.add(c.session.conn)
        return c.outbox.put_pose(source, data, now)

    def final(self, c: Conn, data: bytes, now: float, code: int, reason: str) -> None:
        c.outbox.put_final(data, now, code, reason)
        self._dirty.add(c.session.conn)

    def abort(self, conn: int) -> None:
        self._aborts.add(conn)

    def pop_dirty(self) -> set[int]:
        out, self._dirty = self._dirty, set()
        return out

    def pop_aborts(self) -> set[int]:
        out, self._aborts = self._aborts, set()
        return out
