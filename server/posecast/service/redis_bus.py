"""The Redis backend of the bus (``--redis URL``): how nodes share rooms.

Redis holds, per room, a hash of who plays in it where and, per node, a heartbeat
key that expires ``redis_node_ttl_s`` after the node's last heartbeat. Pub/sub
carries one channel per room: ``join``/``leave`` announcements and one ``tick``
batch per node per tick. A node subscribes only to the rooms it has a local
audience in. ``docs/scale-out.md`` gives the reasoning, key names and bounds.

Three tasks per connection, under a supervisor that reconnects with jittered
exponential backoff: ``_commands`` owns the command connection and sends, in
order, everything the hub asked for (one pipelined round trip for all of it: pose
batches are latest-wins per room while a round trip is in flight); ``_listen``
owns the pub/sub connection; ``_heartbeat`` queues a full resync every
``redis_heartbeat_s``: refresh the node key, re-assert every local player, read
every watched room's hash, drop the entries of dead nodes (announcing their
leave) and hand each room's live members to the hub. Any Redis error ends the
connection; the hub keeps serving local play meanwhile, since nothing here is
awaited by the tick.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import random
import time
from collections import deque
from dataclasses import dataclass, field
from typing import Any

from redis.asyncio import Redis
from redis.asyncio.client import PubSub
from redis.asyncio.retry import Retry
from redis.backoff import NoBackoff

from posecast.service.bus import Bus, BusMessage, decode_message, deliver, encode_message
from posecast.service.config import ServerConfig
from posecast.service.metrics import Metrics

log = logging.getLogger("posecast.bus")
_POLL_S = 0.05  # longest wait before a (un)subscription is sent; messages never wait
_MAX_EVENTS = 64  # stale/active presence kept per room while a round trip is in flight

# Delete a member entry only if ``node`` still owns it (the player may have moved to
# another node since), then announce the leave; one atomic round trip.
_LEAVE_LUA = """
local v = redis.call('HGET', KEYS[1], ARGV[1])
if v and string.sub(v, 1, #ARGV[2] + 1) == ARGV[2] .. '\\t' then
  redis.call('HDEL', KEYS[1], ARGV[1])
end
return redis.call('PUBLISH', ARGV[3], ARGV[4])
"""


@dataclass
class _Batch:
    poses: dict[str, bytes] = field(default_factory=dict)
    events: list[bytes] = field(default_factory=list)


class RedisBus(Bus):
    def __init__(self, cfg: ServerConfig, metrics: Metrics, node: str) -> None:
        super().__init__(node)
        self.cfg, self.metrics = cfg, metrics
        self._prefix = cfg.redis_prefix
        self._ttl_ms = int(cfg.redis_node_ttl_s * 1000)
        self._watched: dict[str, bytes] = {}  # room -> its channel
        self._rooms: dict[bytes, str] = {}  # channel -> room
        self._ops: deque[tuple[Any, ...]] = deque()
        self._ticks: dict[str, _Batch] = {}
        self._wake = asyncio.Event()
        self._connected = False
        self._stopping = False
        self._full_sync_queued = False
        self._task: asyncio.Task[None] | None = None
        self._lost: asyncio.TimerHandle | None = None
        self._last_error = "not connected yet"
        self._leave_sha = ""  # _LEAVE_LUA, loaded on every (re)connect
        self._idle = True
        self._failures = 0  # connection attempts failed since the last success

    # --- names ----------------------------------------------------------------------------

    def channel(self, room: str) -> str:
        return f"{self._prefix}:room:{{{room}}}"  # {room}: one Cluster slot per room

    def members_key(self, room: str) -> str:
        return f"{self._prefix}:members:{{{room}}}"

    def node_key(self, node: str) -> str:
        return f"{self._prefix}:node:{node}"

    # --- what the hub calls (never blocks) -----------------------------------------------

    @property
    def healthy(self) -> bool:
        return self._connected

    @property
    def status(self) -> str:
        return "ok" if self._connected else f"redis unavailable: {self._last_error}"

    def watch(self, room: str) -> None:
        self._watched[room] = ch = self.channel(room).encode()
        self._rooms[ch] = room
        self._queue(("sync", (room,), False))

    def unwatch(self, room: str) -> None:
        ch = self._watched.pop(room, None)
        if ch is not None:
            self._rooms.pop(ch, None)

    def joined(self, room: str, player: str, name: str) -> None:
        self._queue(("join", room, player, name))

    def left(self, room: str, player: str) -> None:
        self._queue(("leave", room, player, self.node))

    def publish(self, room: str, poses: list[tuple[str, bytes]], events: list[bytes]) -> None:
        if not self._connected:
            self.metrics.bus_dropped.labels("disconnected").inc()
            return
        batch = self._ticks.get(room)
        if batch is None:
            self._ticks[room] = batch = _Batch()
        elif batch.poses:
            self.metrics.bus_dropped.labels("superseded").inc()
        batch.poses.update(poses)
        batch.events = (batch.events + events)[-_MAX_EVENTS:]
        self._wake.set()

    def _queue(self, op: tuple[Any, ...]) -> None:
        if not self._connected:
            return  # the heartbeat after the reconnect re-asserts the whole local state
        if op[0] == "sync" and op[2]:
            if self._full_sync_queued:
                return
            self._full_sync_queued = True
        self._ops.append(op)
        self._idle = False
        self._wake.set()

    # --- lifecycle ------------------------------------------------------------------------

    async def start(self) -> None:
        self._task = asyncio.create_task(self._run(), name="posecast-redis-bus")

    async def stop(self) -> None:
        """Send what is queued (the shutdown's leaves), delete the node key, disconnect."""
        self._stopping = True
        self._queue(("bye",))
        deadline = time.monotonic() + self.cfg.redis_timeout_s
        while self._connected and not self._idle and time.monotonic() < deadline:
            await asyncio.sleep(0.01)
        if self._task is not None:
            self._task.cancel()
            with contextlib.suppress(asyncio.CancelledError):
                await self._task

    async def _run(self) -> None:
        backoff = 0.1
        while not self._stopping:
            began = time.monotonic()
            try:
                await self._session()
            except Exception as exc:  # RedisError, OSError, or a group of them
                self._last_error = _describe(exc)
                self._failures += 1
                if self._failures == 1 or self._failures % 20 == 0:  # not a line per retry
                    extra = {"error": self._last_error, "failures": self._failures}
                    log.warning("bus down", extra=extra)
            if time.monotonic() - began > 10 * backoff:
                backoff = 0.1  # it was up for a while: a fresh failure starts over
            await asyncio.sleep(random.uniform(backoff / 2, backoff))
            backoff = min(2 * backoff, self.cfg.redis_backoff_max_s)

    async def _session(self) -> None:
        t = self.cfg.redis_timeout_s
        client = Redis.from_url(
            self.cfg.redis_url,
            socket_timeout=t,
            socket_connect_timeout=t,
            retry=Retry(NoBackoff(), 0),  # the supervisor retries, with its own backoff
        )
        pubsub = client.pubsub()
        try:
            await client.ping()
            await pubsub.subscribe(f"{self._prefix}:ctl")  # opens the pub/sub connection
            self._leave_sha = await client.script_load(_LEAVE_LUA)
            self._set_connected(True)
            async with asyncio.TaskGroup() as tg:
                tg.create_task(self._commands(client))
                tg.create_task(self._listen(pubsub))
                tg.create_task(self._heartbeat())
        finally:
            self._set_connected(False)
            for closing in (pubsub, client):
                with contextlib.suppress(Exception):
                    await closing.aclose()

    def _set_connected(self, up: bool) -> None:
        if up == self._connected:
            return
        self._connected = up
        self.metrics.bus_connected.set(int(up))
        self._ops.clear()
        self._ticks.clear()
        self._full_sync_queued = False
        if self._lost is not None:
            self._lost.cancel()
            self._lost = None
        if up:
            self._failures = 0
            self.metrics.bus_reconnects.inc()
            log.info("bus connected", extra={"node": self.node})
        elif not self._stopping:
            # Remote players are unconfirmed from now on; past the node TTL they count
            # as gone, like the players of a dead node (the resync brings them back).
            loop = asyncio.get_running_loop()
            self._lost = loop.call_later(self.cfg.redis_node_ttl_s, self._report_lost)

    def _report_lost(self) -> None:
        if self.sink is not None and not self._connected:
            self.sink.remote_lost(time.monotonic())
            self.after()

    # --- the three tasks of one connection -----------------------------------------------

    async def _heartbeat(self) -> None:
        while True:
            self._queue(("sync", (), True))
            await asyncio.sleep(self.cfg.redis_heartbeat_s)

    async def _commands(self, client: Redis) -> None:
        while True:
            self._idle = True
            await self._wake.wait()
            self._wake.clear()
            self._idle = False
            while self._ops or self._ticks:
                pipe = client.pipeline(transaction=False)
                while self._ops:
                    op = self._ops.popleft()
                    if op[0] == "sync":
                        await self._execute(pipe)
                        pipe = client.pipeline(transaction=False)
                        await self._sync(client, op[1], full=op[2])
                    else:
                        self._op(pipe, op)
                ticks, self._ticks = self._ticks, {}
                for room, b in ticks.items():
                    m = BusMessage(
                        "tick", self.node, poses=tuple(b.poses.items()), events=(*b.events,)
                    )
                    self._publish(pipe, room, m)
                await self._execute(pipe)

    def _op(self, pipe: Any, op: tuple[Any, ...]) -> None:
        if op[0] == "join":
            _, room, player, name = op
            key = self.members_key(room)
            pipe.hset(key, player, f"{self.node}\t{name}")
            pipe.pexpire(key, 2 * self._ttl_ms)
            self._publish(pipe, room, BusMessage("join", self.node, player, name))
        elif op[0] == "leave":
            _, room, player, node = op
            data = encode_message(BusMessage("leave", node, player))
            self._count("out", "leave", data)
            key, channel = self.members_key(room), self.channel(room)
            pipe.evalsha(self._leave_sha, 1, key, player, node, channel, data)
        elif op[0] == "bye":
            pipe.delete(self.node_key(self.node))

    def _publish(self, pipe: Any, room: str, m: BusMessage) -> None:
        data = encode_message(m)
        self._count("out", m.kind, data)
        pipe.publish(self.channel(room), data)

    def _count(self, direction: str, kind: str, data: bytes) -> None:
        self.metrics.bus_messages.labels(direction, kind).inc()
        self.metrics.bus_bytes.labels(direction).inc(len(data))

    async def _execute(self, pipe: Any) -> list[Any]:
        if not len(pipe):
            return []
        t0 = time.perf_counter()
        out: list[Any] = await pipe.execute()
        self.metrics.bus_roundtrip.observe(time.perf_counter() - t0)
        return out

    async def _sync(self, client: Redis, only: tuple[str, ...], *, full: bool) -> None:
        """Re-assert this node (``full``), then reconcile the watched rooms in ``only``
        (all of them when empty) with Redis, and report each to the hub."""
        if self.sink is None:
            return
        if full:
            self._full_sync_queued = False
        issued = time.monotonic()
        local = self.sink.local_rooms()
        rooms = [r for r in (only or tuple(self._watched)) if r in self._watched]
        pipe = client.pipeline(transaction=False)
        if full:
            pipe.set(self.node_key(self.node), b"1", px=self._ttl_ms)
            for room, players in local.items():
                if players:
                    key = self.members_key(room)
                    pipe.hset(key, mapping={p: f"{self.node}\t{n}" for p, n in players.items()})
                    pipe.pexpire(key, 2 * self._ttl_ms)
        first = len(pipe)
        for room in rooms:
            pipe.hgetall(self.members_key(room))
        replies = (await self._execute(pipe))[first:]
        tables = {room: _parse_members(raw) for room, raw in zip(rooms, replies, strict=True)}
        nodes = sorted({n for t in tables.values() for n, _ in t.values()} - {self.node})
        pipe = client.pipeline(transaction=False)
        for n in nodes:
            pipe.exists(self.node_key(n))
        alive = {n for n, up in zip(nodes, await self._execute(pipe), strict=True) if up}
        pipe = client.pipeline(transaction=False)
        local = self.sink.local_rooms()  # now, after the reads: who is still here
        for room, table in tables.items():
            mine = local.get(room, {})
            for player, (node, _) in table.items():
                if (node == self.node and player not in mine) or (
                    node != self.node and node not in alive
                ):
                    self._op(pipe, ("leave", room, player, node))  # reaped, and announced
        await self._execute(pipe)
        now = time.monotonic()
        for room, table in tables.items():
            live = {p: v for p, v in table.items() if v[0] in alive}
            self.sink.remote_snapshot(room, live, issued, now)
        self.after()

    async def _listen(self, pubsub: PubSub) -> None:
        subscribed: set[bytes] = set()
        while True:
            want = set(self._rooms)
            if want - subscribed:
                await pubsub.subscribe(*(want - subscribed))
            if subscribed - want:
                await pubsub.unsubscribe(*(subscribed - want))
            subscribed = want
            msg = await pubsub.get_message(timeout=_POLL_S)
            delivered = False
            while msg is not None:
                room = self._rooms.get(msg["channel"])
                if room is not None and msg["type"] == "message":
                    delivered |= self._receive(room, msg["data"])
                elif room is not None and msg["type"] == "subscribe":
                    self._queue(("sync", (room,), False))  # announcements flow: now read
                msg = await pubsub.get_message(timeout=0)
            if delivered:
                self.after()

    def _receive(self, room: str, data: bytes) -> bool:
        m = decode_message(data)
        if m is None:
            self.metrics.bus_dropped.labels("undecodable").inc()
            return False
        if m.node == self.node or self.sink is None:
            return False  # our own publish, echoed by the channel
        self._count("in", m.kind, data)
        deliver(self.sink, room, m, time.monotonic())
        return True


def _parse_members(raw: dict[bytes, bytes]) -> dict[str, tuple[str, str]]:
    out = {}
    for player, value in raw.items():
        node, _, name = value.decode("utf-8", "replace").partition("\t")
        out[player.decode("utf-8", "replace")] = (node, name)
    return out


def _describe(exc: BaseException) -> str:
    if isinstance(exc, BaseExceptionGroup):
        return "; ".join(_describe(e) for e in exc.exceptions)
    return f"{type(exc).__name__}: {exc}"[:200]
