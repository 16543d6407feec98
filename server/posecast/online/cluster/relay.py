"""The node-local relay: what rooms spanning a node's worker processes share.

``posecast serve --workers N`` (N > 1, no ``--redis``) runs N serving processes on
one port; their players meet in rooms whatever process the kernel handed each
connection to. The supervisor runs one :class:`Relay` on a Unix-domain socket and
every worker's :class:`~posecast.online.cluster.local.LocalBus` connects to it. The
relay plays, across processes, the part :class:`~posecast.online.cluster.memory.MemoryBroker`
plays in one: the member list of every room, which worker receives which room, the
burned tokens. A worker's connection closing (the worker died or stopped) drops its
members, and the relay announces their ``leave`` to the rest, as Redis's heartbeat
does for a dead node.

The wire is length-prefixed frames (:func:`frame`): ``u32`` length of what follows,
then an op byte, a room (one length byte, then UTF-8) and a payload. A payload of
``join``, ``leave``, ``tick`` and ``burn`` is the bus's own message
(:func:`~posecast.online.cluster.bus.encode_message`), forwarded as it came: a tick's
pose rows are never decoded on the way. The ops:

===========  ===============  ===========================================================
op           direction        payload
===========  ===============  ===========================================================
``HELLO``    worker -> relay  msgpack ``[node, worker label]``; the relay answers with
                              every live burned token (``BURN``)
``WATCH``    worker -> relay  none: receive ``room`` from now; answered by ``SNAPSHOT``
``UNWATCH``  worker -> relay  none
``JOIN``     worker -> relay  the ``join`` message: recorded, forwarded as ``MSG``
``LEAVE``    worker -> relay  the ``leave`` message: recorded, forwarded as ``MSG``
``TICK``     worker -> relay  the ``tick`` message: forwarded as ``MSG``, never decoded
``BURN``     both ways        the ``burn`` message
``MSG``      relay -> worker  a ``join``, ``leave`` or ``tick`` of another worker
``SNAPSHOT`` relay -> worker  msgpack ``{player: [node, name]}``: ``room``'s members on
                              the other workers, when the ``WATCH`` was read
``SCRAPE``   both ways        ``u32`` id: worker -> relay, "the node's metrics, please";
                              relay -> worker, "yours, please"
``METRICS``  both ways        ``u32`` id, then Prometheus text: the answer to ``SCRAPE``
===========  ===============  ===========================================================

One connection's frames are handled in order and each worker's are written in order,
so a ``SNAPSHOT`` follows every message of the room sent before the ``WATCH`` was
read and precedes every one after: no join or leave falls in the gap.
"""

from __future__ import annotations

import asyncio
import contextlib
import enum
import logging
import struct
import time
from collections.abc import Awaitable, Callable, Iterator
from dataclasses import dataclass, field

import msgpack

from posecast.online.cluster.bus import Burns, BusMessage, decode_message, encode_message

log = logging.getLogger("posecast.relay")

_LEN = struct.Struct("!I")
_ID = struct.Struct("!I")
MAX_FRAME_BYTES = 64 << 20  # far above any tick (a room of 32 poses is ~12 KB)
# A receiver this far behind gets no more pose batches until it catches up (a pose
# batch is superseded 16.7 ms later anyway); announcements are never dropped.
MAX_BACKLOG_BYTES = 4 << 20
SCRAPE_TIMEOUT_S = 0.5  # a stuck worker never stalls the node's scrape longer


class Op(enum.IntEnum):
    HELLO = 1
    WATCH = 2
    UNWATCH = 3
    JOIN = 4
    LEAVE = 5
    TICK = 6
    BURN = 7
    MSG = 8
    SNAPSHOT = 9
    SCRAPE = 10
    METRICS = 11


def frame(op: Op, room: str = "", payload: bytes = b"") -> bytes:
    """One frame: ``u32`` length, op, room length, room, payload."""
    r = room.encode()
    return _LEN.pack(2 + len(r) + len(payload)) + bytes((op, len(r))) + r + payload


class FrameReader:
    """Frames out of a byte stream, as they complete (sans I/O)."""

    def __init__(self) -> None:
        self._buf = bytearray()

    def feed(self, data: bytes) -> Iterator[tuple[Op, str, bytes]]:
        """``(op, room, payload)`` of every frame ``data`` completes. Raises
        ``ValueError`` for a frame that is too large, empty or of an unknown op."""
        buf = self._buf
        buf += data
        at = 0
        try:
            while len(buf) - at >= 4:
                (n,) = _LEN.unpack_from(buf, at)
                if n < 2 or n > MAX_FRAME_BYTES:
                    raise ValueError(f"relay frame of {n} bytes")
                if len(buf) - at - 4 < n:
                    break
                body = bytes(buf[at + 4 : at + 4 + n])
                at += 4 + n
                rlen = body[1]
                yield Op(body[0]), body[2 : 2 + rlen].decode(), body[2 + rlen :]
        finally:
            del buf[:at]


def scrape_id(payload: bytes) -> int:
    return int(_ID.unpack_from(payload)[0])


def metrics_payload(ident: int, text: bytes) -> bytes:
    return _ID.pack(ident) + text


@dataclass(eq=False)
class _Worker:
    """One worker's connection, as the relay holds it."""

    writer: asyncio.StreamWriter
    node: str = ""
    label: str = "?"
    rooms: set[str] = field(default_factory=set)  # watched

    def send(self, data: bytes) -> None:
        if not self.writer.is_closing():
            self.writer.write(data)

    @property
    def backlog(self) -> int:
        return self.writer.transport.get_write_buffer_size()


@dataclass
class RelayCounts:
    """What the relay did, for the supervisor's metrics."""

    forwarded: int = 0  # frames written to a worker
    dropped: int = 0  # pose batches not written: the receiver was MAX_BACKLOG_BYTES behind


class Relay:
    """The supervisor's side: a Unix-domain server, every room's members, the burns.

    ``own_metrics`` renders the supervisor's own metrics, ``merge`` joins every
    worker's and the supervisor's exposition (label, text) into one scrape."""

    def __init__(
        self,
        path: str,
        *,
        own_metrics: Callable[[], bytes],
        merge: Callable[[list[tuple[str, bytes]]], bytes],
        replay_cache: int = 100_000,
        token_leeway_s: float = 5.0,
    ) -> None:
        self.path = path
        self.own_metrics, self.merge = own_metrics, merge
        self.members: dict[str, dict[str, tuple[_Worker, str]]] = {}  # room -> player -> owner
        self.subscribers: dict[str, list[_Worker]] = {}
        self.workers: list[_Worker] = []
        self.burns = Burns(replay_cache, token_leeway_s)
        self.counts = RelayCounts()
        self._server: asyncio.Server | None = None
        self._scrapes: dict[int, dict[_Worker, bytes]] = {}
        self._scrape_done: dict[int, asyncio.Event] = {}
        self._next_id = 0
        self._tasks: set[asyncio.Task[None]] = set()

    async def start(self) -> None:
        self._server = await asyncio.start_unix_server(self._serve, self.path)

    async def stop(self) -> None:
        if self._server is not None:
            self._server.close()
        for w in list(self.workers):
            w.writer.close()
        for task in list(self._tasks):
            task.cancel()
            with contextlib.suppress(asyncio.CancelledError):
                await task

    # --- one worker's connection -----------------------------------------------------------

    async def _serve(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        w = _Worker(writer)
        self.workers.append(w)
        frames = FrameReader()
        try:
            while data := await reader.read(1 << 16):
                for op, room, payload in frames.feed(data):
                    self.handle(w, op, room, payload)
        except (ConnectionError, ValueError) as exc:
            log.warning("relay connection dropped", extra={"worker": w.label, "why": str(exc)})
        finally:
            self.drop(w)
            writer.close()

    def handle(self, w: _Worker, op: Op, room: str, payload: bytes) -> None:
        """One frame from worker ``w``."""
        if op is Op.TICK:
            self._forward(w, room, frame(Op.MSG, room, payload), droppable=True)
        elif op is Op.JOIN or op is Op.LEAVE:
            m = decode_message(payload)
            if m is None:
                return
            members = self.members.setdefault(room, {})
            if op is Op.JOIN:
                members[m.player] = (w, m.name)
            elif members.get(m.player, (None,))[0] is w:
                del members[m.player]
            if not members:
                del self.members[room]
            self._forward(w, room, frame(Op.MSG, room, payload))
        elif op is Op.WATCH:
            w.rooms.add(room)
            subs = self.subscribers.setdefault(room, [])
            if w not in subs:
                subs.append(w)
            live = {
                p: [owner.node, name]
                for p, (owner, name) in self.members.get(room, {}).items()
                if owner is not w
            }
            w.send(frame(Op.SNAPSHOT, room, msgpack.packb(live, use_bin_type=True)))
        elif op is Op.UNWATCH:
            self._unwatch(w, room)
        elif op is Op.BURN:
            m = decode_message(payload)
            if m is not None and m.kind == "burn":
                self.burns.add(m.player, m.exp, time.time())
                out = frame(Op.BURN, "", payload)
                for other in self.workers:
                    if other is not w:
                        other.send(out)
                        self.counts.forwarded += 1
        elif op is Op.HELLO:
            w.node, w.label = (str(x) for x in msgpack.unpackb(payload, raw=False))
            for jti, exp in self.burns.live(time.time()).items():
                w.send(frame(Op.BURN, "", encode_message(BusMessage("burn", "", jti, exp=exp))))
        elif op is Op.SCRAPE:
            self._spawn(self._scrape(w, scrape_id(payload)))
        elif op is Op.METRICS:
            ident = scrape_id(payload)
            got = self._scrapes.get(ident)
            if got is not None:
                got[w] = payload[_ID.size :]
                if len(got) >= len(self.workers):
                    self._scrape_done[ident].set()

    def _forward(self, w: _Worker, room: str, data: bytes, droppable: bool = False) -> None:
        for other in self.subscribers.get(room, ()):
            if other is w:
                continue
            if droppable and other.backlog > MAX_BACKLOG_BYTES:
                self.counts.dropped += 1
                continue
            other.send(data)
            self.counts.forwarded += 1

    def _unwatch(self, w: _Worker, room: str) -> None:
        w.rooms.discard(room)
        subs = self.subscribers.get(room, [])
        if w in subs:
            subs.remove(w)
        if not subs:
            self.subscribers.pop(room, None)

    def drop(self, w: _Worker) -> None:
        """``w``'s connection is gone: its rooms unwatched, its players announced gone."""
        if w not in self.workers:
            return
        self.workers.remove(w)
        for room in list(w.rooms):
            self._unwatch(w, room)
        for room, members in list(self.members.items()):
            for player in [p for p, (owner, _) in members.items() if owner is w]:
                del members[player]
                leave = encode_message(BusMessage("leave", w.node, player))
                self._forward(w, room, frame(Op.MSG, room, leave))
            if not members:
                del self.members[room]
        for got in self._scrapes.values():  # a scrape in progress no longer waits for it
            got.pop(w, None)
        for ident, got in self._scrapes.items():
            if len(got) >= len(self.workers):
                self._scrape_done[ident].set()

    # --- one scrape of the whole node ---------------------------------------------------------

    async def _scrape(self, asker: _Worker, ident: int) -> None:
        merged = await self.scrape()
        asker.send(frame(Op.METRICS, "", metrics_payload(ident, merged)))

    async def scrape(self, timeout_s: float = SCRAPE_TIMEOUT_S) -> bytes:
        """Every worker's metrics and the supervisor's, merged; a worker that does not
        answer within ``timeout_s`` is left out (its series are missing, not stale)."""
        self._next_id += 1
        ident = self._next_id
        got: dict[_Worker, bytes] = {}
        done = asyncio.Event()
        self._scrapes[ident], self._scrape_done[ident] = got, done
        ask = frame(Op.SCRAPE, "", _ID.pack(ident))
        for w in self.workers:
            w.send(ask)
        if not self.workers:
            done.set()
        try:
            with contextlib.suppress(TimeoutError):
                await asyncio.wait_for(done.wait(), timeout_s)
        finally:
            del self._scrapes[ident], self._scrape_done[ident]
        parts = sorted(((w.label, text) for w, text in got.items()), key=_worker_order)
        return self.merge([*parts, ("supervisor", self.own_metrics())])

    def _spawn(self, coro: Awaitable[None]) -> None:
        task = asyncio.ensure_future(coro)
        self._tasks.add(task)
        task.add_done_callback(self._tasks.discard)


def _worker_order(part: tuple[str, bytes]) -> tuple[int, str]:
    label = part[0]
    return (int(label), "") if label.isdigit() else (1 << 30, label)
