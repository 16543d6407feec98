"""One client's outgoing messages: latest-wins pose slots plus a small reliable queue.

See ``docs/broadcast.md`` for the reasoning. In short: a pose supersedes the previous
pose of the same avatar, so a client that falls behind is sent the newest pose of
each avatar, never a backlog; control messages (welcome, presence, errors, pong, bye)
must all arrive, in order, so they wait in a bounded FIFO, and a client that lets
that FIFO overflow, or whose writer makes no progress for too long, is cut off.

Pure: the asyncio writer task in :mod:`posecast.online.shell.app` calls :meth:`take`,
sends what it got, then calls :meth:`sent`. Times are passed in.

A v2 client's outbox has a :class:`~posecast.online.core.posestream.PoseStream`: its
slots hold prepared records instead of pose messages, and :meth:`take` turns the
slots taken into ONE ``poses`` message (more only where one would pass 16384 bytes: a
backend watching many full rooms), moving the client's references on.
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass, field

from posecast.online.core.posestream import PoseStream, Slot


@dataclass
class Outbox:
    """Latest-wins slots keyed by source player, and a FIFO of ``reliable_max`` entries."""

    reliable_max: int
    stream: PoseStream | None = None  # v2: records, sent as one poses message
    _reliable: deque[bytes] = field(default_factory=deque)
    _poses: dict[str, bytes | Slot] = field(default_factory=dict)
    _pending_since: float | None = None  # data waiting (or in flight) since then
    _in_flight: bool = False
    overflowed: bool = False
    superseded: int = 0  # poses replaced before they were sent
    closed: bool = False
    close_code: int = 1000  # WebSocket close code once the final message is out
    close_reason: str = ""

    def put_pose(self, player: str, data: bytes | Slot, now: float) -> bool:
        """Queue ``player``'s newest pose, replacing any unsent one of the same player;
        ``True`` when one was replaced."""
        if self.closed:
            return False
        replaced = self._poses.pop(player, None) is not None
        self.superseded += replaced
        self._poses[player] = data  # re-inserted last: slots go out oldest-update first
        self._mark(now)
        return replaced

    def put_reliable(self, data: bytes, now: float) -> bool:
        """Queue a control message; ``False`` (and :attr:`overflowed`) when full."""
        if self.closed:
            return True
        if len(self._reliable) >= self.reliable_max:
            self.overflowed = True
            return False
        self._reliable.append(data)
        self._mark(now)
        return True

    def put_final(self, data: bytes, now: float, code: int = 1000, reason: str = "") -> None:
        """Queue a last control message (fatal error, bye) even when the queue is full,
        drop pending poses, refuse anything after it, then close with ``code``."""
        if self.closed:
            return
        self.close_code, self.close_reason = code, reason
        self._poses.clear()
        self._reliable.append(data)
        self._mark(now)
        self.closed = True

    def drop_pose(self, player: str) -> None:
        """Forget ``player``'s unsent pose (it left: a pose sent after its ``leave``
        would bring back an avatar the client has just removed)."""
        self._poses.pop(player, None)

    def held(self, player: str) -> bool:
        """Whether an unsent pose of ``player`` waits in its slot."""
        return player in self._poses

    def take(self, now: float = 0.0) -> list[bytes]:
        """Everything to send now: control messages first, then one pose per player
        (v2: one ``poses`` message of them all)."""
        out = list(self._reliable)
        if self.stream is not None:
            slots = [(p, s) for p, s in self._poses.items() if isinstance(s, Slot)]
            if slots:
                out.extend(self.stream.messages(slots, now))
        else:
            out.extend(self._poses.values())  # type: ignore[arg-type]  # v1 slots hold bytes
        self._reliable.clear()
        self._poses.clear()
        self._in_flight = bool(out)
        return out

    def sent(self, now: float) -> None:
        """The writer finished sending what :meth:`take` gave it: that is progress."""
        self._in_flight = False
        self._pending_since = now if self.pending else None

    @property
    def pending(self) -> bool:
        return bool(self._reliable or self._poses)

    @property
    def drained(self) -> bool:
        """Nothing queued and nothing in flight."""
        return not self.pending and not self._in_flight

    def stalled_for(self, now: float) -> float:
        """Seconds the writer has had data and made no progress (0 when drained)."""
        return 0.0 if self._pending_since is None else max(0.0, now - self._pending_since)

    def pause(self, late_s: float) -> None:
        """The server was ``late_s`` late: its writers could not run, so that time
        is not the client's (the slow-consumer clock stops for it)."""
        if self._pending_since is not None:
            self._pending_since += late_s

    def _mark(self, now: float) -> None:
        if self._pending_since is None:
            self._pending_since = now
