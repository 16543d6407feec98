"""The Redis backend of the bus (``--redis URL``): how nodes share rooms.

Redis holds, per room, a hash of who plays in it where and, per node, a heartbeat
key that expires ``redis_node_ttl_s`` after the node's last heartbeat. Pub/sub
carries one channel per room: ``join``/``leave`` announcements and one ``tick``
batch per node per tick. A node subscribes only to the rooms it has a local
audience in. Key names and commands are :mod:`posecast.online.cluster.redis_store`'s;
``docs/scale-out.md`` gives the reasoning and the bounds.

Three tasks per connection, under a supervisor that reconnects with jittered
exponential backoff: ``_commands`` owns the command connection and sends, in
order, everything the hub asked for (one pipelined round trip for all of it: pose
batches are latest-wins per room while a round trip is in flight, and every round
trip, each of a resync's too, carries the latest); ``_listen``
owns the pub/sub connection (and PINGs it when it has been quiet for a heartbeat:
a connection that died silently never raises); ``_heartbeat`` queues a full resync
every ``redis_heartbeat_s``: refresh the node key, re-assert every local player,
read every watched room's hash, drop the entries of dead nodes (announcing their
leave) and hand each room's live members to the hub. Any Redis error, and a PING
unanswered for ``redis_timeout_s``, ends the connection; the hub keeps serving local
play meanwhile, since nothing here is awaited by the tick.

What a disconnected node could not send is made good after the reconnect: the
joins of players admitted meanwhile are written and announced (they replace the same
player on other nodes, as a join does), and the node's own burned tokens are
announced again, every burn it knows written back (a Redis restarted empty lost them).
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import random
import time
from collections import deque
from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field
from typing import Any

from redis.asyncio import Redis
from redis.asyncio.client import PubSub
from redis.asyncio.retry import Retry
from redis.backoff import NoBackoff

from posecast.online.cluster.bus import Burns, Bus, BusMessage, decode_message, deliver
from posecast.online.cluster.redis_store import RedisStore
from posecast.online.config import ServerConfig
from posecast.online.metrics import Metrics
from posecast.online.protocol.pose_out import PoseOut

log = logging.getLogger("posecast.bus")
_POLL_S = 0.05  # longest wait before a (un)subscription is sent; messages never wait
_MAX_EVENTS = 64  # stale/active presence kept per room while a round trip is in flight


@dataclass
class _Batch:
    poses: dict[str, PoseOut] = field(default_factory=dict)  # player -> newest pose
    events: list[bytes] = field(default_factory=list)


class RedisBus(Bus):
    unavailable = "redis unavailable"

    def __init__(self, cfg: ServerConfig, metrics: Metrics, node: str) -> None:
        super().__init__(node)
        self.cfg, self.metrics = cfg, metrics
        self.store = RedisStore(
            cfg.redis_prefix, node, cfg.redis_node_ttl_s, metrics, cfg.redis_heartbeat_s / 2,
            timeout_s=cfg.redis_timeout_s,
        )  # fmt: skip
        self.store.piggyback = self._piggyback
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
        self._connected_at = 0.0
        self._last_error = "not connected yet"
        self._idle = True
        self._failures = 0  # connection attempts failed since the last success
        self._load_burned = False
        self._ctl = self.store.ctl_channel.encode()
        # Every burn this node knows (its own, heard, loaded), and its own: a Redis
        # restarted empty has lost the first, those burned while disconnected never went out.
        self._burns = Burns(cfg.replay_cache, cfg.token_leeway_s)
        self._own = Burns(cfg.replay_cache, cfg.token_leeway_s)
        # Local players, (room, player) -> the number of the bus.joined() call that made
        # them (one counter, so "joined before that moment" is a comparison).
        self._seq = 0
        self._players: dict[tuple[str, str], int] = {}
        # Of those, the ones whose join is not known to have reached Redis (made while
        # disconnected, or lost with a connection): announced after the reconnect.
        self._unsent: dict[tuple[str, str], int] = {}
        # Of those, the ones whose entry this connection has written (join queued, or
        # claimed by a heartbeat), each before any read dequeued after it.
        self._asserted: dict[tuple[str, str], int] = {}

    # --- what the hub calls (never blocks) -----------------------------------------------

    @property
    def healthy(self) -> bool:
        return self._connected

    @property
    def status(self) -> str:
        return "ok" if self._connected else f"redis unavailable: {self._last_error}"

    def watch(self, room: str) -> None:
        self._watched[room] = ch = self.store.channel(room).encode()
        self._rooms[ch] = room
        self._queue(("sync", (room,), False))

    def unwatch(self, room: str) -> None:
        ch = self._watched.pop(room, None)
        if ch is not None:
            self._rooms.pop(ch, None)

    def joined(self, room: str, player: str, name: str) -> None:
        self._seq += 1
        key = (room, player)
        self._players[key] = self._unsent[key] = self._seq
        if self._connected:  # else the heartbeat after the reconnect announces it
            self._asserted[key] = self._seq
            self._queue(("join", room, player, name, self._seq))

    def left(self, room: str, player: str) -> None:
        key = (room, player)
        for held in (self._players, self._unsent, self._asserted):
            held.pop(key, None)
        self._queue(("leave", room, player, self.node))

    def burned(self, jti: str, exp: int) -> None:
        wall = time.time()
        self._burns.add(jti, exp, wall)
        self._own.add(jti, exp, wall)
        self._queue(("burn", jti, exp))  # while disconnected: re-sent after the reconnect

    def publish(self, room: str, poses: list[PoseOut], events: list[bytes]) -> None:
        if not self._connected:
            self.metrics.bus_dropped.labels("disconnected").inc()
            return
        batch = self._ticks.get(room)
        if batch is None:
            self._ticks[room] = batch = _Batch()
        elif batch.poses:
            self.metrics.bus_dropped.labels("superseded").inc()
        batch.poses.update((p.player, p) for p in poses)
        batch.events = (batch.events + events)[-_MAX_EVENTS:]
        self._wake.set()

    def _queue(self, op: tuple[Any, ...]) -> None:
        if not self._connected:
            return  # the heartbeat after the reconnect re-asserts the whole local state
        if op[0] == "sync" and self._stopping:
            return  # the goodbye deleted the node key: no heartbeat may restore it
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
            await pubsub.subscribe(self.store.ctl_channel)  # also opens the pub/sub connection
            self._load_burned = True
            await self.store.prepare(client)
            if self._stopping:  # stop()'s cancel may have been swallowed: see _check_cancel
                return
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
        self._asserted.clear()  # a new connection (and maybe an empty Redis): not yet
        self._full_sync_queued = False
        if self._lost is not None:
            self._lost.cancel()
            self._lost = None
        if up:
            self._connected_at = time.monotonic()
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
        period = self.cfg.redis_heartbeat_s
        next_at = time.monotonic()
        while True:  # at a fixed rate: the node key's TTL budget assumes it
            self._queue(("sync", (), True))
            next_at = max(next_at + period, time.monotonic())
            await asyncio.sleep(next_at - time.monotonic())

    async def _commands(self, client: Redis) -> None:
        store = self.store
        while True:
            _check_cancel()
            if not self._ops and not self._ticks:
                self._idle = True  # what stop() waits for: everything queued is sent
                await self._wake.wait()
            self._wake.clear()
            self._idle = False
            while self._ops or self._ticks:
                pipe = client.pipeline(transaction=False)
                joins: list[tuple[tuple[str, str], int]] = []
                while self._ops:
                    op, *args = self._ops.popleft()
                    if op == "sync":
                        # The joins queued ahead of the sync are written before its
                        # reads (one connection, in order); one queued behind it (while
                        # a round trip was in flight) is not: see _replaced.
                        upto = self._written_upto()
                        await self._execute(pipe, joins)  # what came before it, in order
                        pipe, joins = client.pipeline(transaction=False), []
                        only, heartbeat = args
                        await self._sync(client, only, heartbeat, upto)
                    elif op == "join":
                        room, player, name, seq = args
                        store.join(pipe, room, player, name)
                        joins.append(((room, player), seq))
                    elif op == "leave":
                        store.leave(pipe, *args)
                    elif op == "burn":
                        store.burn(pipe, *args)
                    elif op == "bye":
                        store.goodbye(pipe)
                self._add_ticks(pipe)  # after every join queued: a join precedes its poses
                await self._execute(pipe, joins)

    def _add_ticks(self, pipe: Any) -> None:
        ticks, self._ticks = self._ticks, {}
        for room, b in ticks.items():
            poses, events = tuple(b.poses.values()), tuple(b.events)
            self.store.publish(
                pipe, room, BusMessage("tick", self.node, poses=poses, events=events)
            )

    def _piggyback(self, pipe: Any) -> None:
        """Every round trip carries the pending pose batches, a resync's too: on a slow
        Redis a resync is several long round trips, and the heartbeat queues the next
        one before it ends, so batches sent only once nothing else is queued would never
        go. Held back while a join that must precede its player's poses has yet to be
        written ahead of them: one queued (behind the resync in progress), or one made
        while disconnected that the heartbeat has not claimed yet (it announces it)."""
        if not self._ticks or any(op[0] == "join" for op in self._ops):
            return
        if self._unsent.keys() <= self._asserted.keys():
            self._add_ticks(pipe)

    def _written_upto(self) -> int:
        """The joins numbered up to this one are written before the next round trip's
        reads: all but those still queued (in order, so from the first of them on)."""
        return next((op[4] for op in self._ops if op[0] == "join"), self._seq + 1) - 1

    async def _execute(self, pipe: Any, joins: list[tuple[tuple[str, str], int]]) -> None:
        await self.store.execute(pipe)
        _check_cancel()
        self._sent(joins)

    def _sent(self, joins: Iterable[tuple[tuple[str, str], int]]) -> None:
        """These joins reached Redis (unless the player left or joined again since)."""
        for key, seq in joins:
            if self._unsent.get(key) == seq:
                del self._unsent[key]

    async def _sync(
        self, client: Redis, only: tuple[str, ...], heartbeat: bool, upto: int = 0
    ) -> None:
        """Reconcile the watched rooms in ``only`` (all when empty) with Redis and report
        each to the hub; a ``heartbeat`` also re-asserts this node and its players.
        ``upto``: the joins numbered up to it were written before these reads."""
        sink = self.sink
        if sink is None:
            return
        if heartbeat:
            self._full_sync_queued = False
        if heartbeat and self._load_burned:  # after a (re)connect: the burns made meanwhile
            self._load_burned = False
            wall = time.time()
            own = self._own.live(wall)
            await self.store.reburn(client, self._burns.live(wall) | own, own)
            for jti, exp in await self.store.burns(
                client, self.cfg.replay_cache, self.cfg.token_leeway_s
            ):
                self._burns.add(jti, exp, wall)
                sink.remote_burn(jti, exp, time.monotonic())
        claim: dict[str, Mapping[str, str]] | None = None
        announce: list[tuple[tuple[str, str], int]] = []
        if heartbeat:
            claim = {r: p for r, p in sink.local_rooms().items() if p}
            announce = self._assert_all(claim)
        issued = time.monotonic()
        rooms = [r for r in (only or tuple(self._watched)) if r in self._watched]
        live = await self.store.reconcile(
            client, rooms, sink.local_rooms, claim=claim, announce={k for k, _ in announce}
        )
        self._sent(announce)
        now = time.monotonic()
        # Just after a (re)connect, Redis may have come back empty and the other nodes
        # not have re-registered yet: for one node TTL a read adds members, never
        # removes them (leaves still arrive as messages; a node that died meanwhile is
        # caught by the next reads).
        keep = now - self._connected_at < self.cfg.redis_node_ttl_s
        for room, members in live.items():
            replaced = self._replaced(room, members, upto)
            sink.remote_snapshot(room, members, issued, now, keep, replaced)
        self.after()

    def _assert_all(
        self, local: Mapping[str, Mapping[str, str]]
    ) -> list[tuple[tuple[str, str], int]]:
        """A heartbeat re-asserts every local player (``local``, the hub's own account):
        the ones whose join never reached Redis are to be announced (returned), the
        rest claimed. Either way their entry is written before the heartbeat's reads."""
        keys = [(room, p) for room, players in local.items() for p in players]
        players = {}
        for key in keys:  # the hub's players are the truth: the bus's account follows it
            seq = self._players.get(key)
            if seq is None:
                self._seq = seq = self._seq + 1
                self._unsent[key] = seq
            players[key] = seq
        self._players = players
        self._unsent = {k: s for k, s in self._unsent.items() if k in players}
        announce = [(k, s) for k, s in self._unsent.items() if k not in self._asserted]
        self._asserted.update(players)
        return announce

    def _replaced(self, room: str, members: Mapping[str, tuple[str, str]], upto: int) -> list[str]:
        """The local players of ``room`` that the read ``members`` (entries of other live
        nodes) lists elsewhere, although this connection wrote their own entry before
        the read: another node has taken them over since, and its join could not reach
        this node (e.g. a Redis outage). A local player whose entry was not written
        before the read (one that just moved here: the read may predate its join) is
        never among them."""
        return [p for p in members if self._asserted.get((room, p), upto + 1) <= upto]

    async def _listen(self, pubsub: PubSub) -> None:
        subscribed: set[bytes] = set()
        # A pub/sub connection that dies silently (a half-open TCP connection, a NAT or
        # firewall that dropped it) never raises: once it has been quiet for a heartbeat,
        # PING it, and give it up when nothing arrives within redis_timeout_s, as a
        # command round trip would be.
        period, limit = self.cfg.redis_heartbeat_s, self.cfg.redis_timeout_s
        heard = pinged = time.monotonic()
        while True:
            _check_cancel()
            want = set(self._rooms)
            if want - subscribed:
                await pubsub.subscribe(*(want - subscribed))
            if subscribed - want:
                await pubsub.unsubscribe(*(subscribed - want))
            subscribed = want
            now = time.monotonic()
            if pinged <= heard and now - heard >= period:
                await pubsub.ping()
                pinged = now
            elif pinged > heard and now - pinged > limit:
                raise TimeoutError(f"no reply on the pub/sub connection in {limit:g} s")
            msg = await pubsub.get_message(timeout=_POLL_S)
            if msg is not None:
                heard = time.monotonic()  # a pong, or anything else: it is alive
            delivered = False
            while msg is not None:
                if msg["channel"] == self._ctl and msg["type"] == "message":
                    self._receive("", msg["data"])
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
        self.store.count("in", m.kind, data)
        if m.kind == "burn":
            self._burns.add(m.player, m.exp, time.time())
        deliver(self.sink, room, m, time.monotonic())
        return True


def _check_cancel() -> None:
    """Raise CancelledError if this task (one of a connection's three) was cancelled.
    The redis client can swallow a cancellation that reaches a task in a round trip:
    its pipeline returns as if nothing happened. The task would then carry on, and the
    TaskGroup that gave the connection up wait for it for ever, the node staying
    "connected" to a dead connection. (Not for the supervisor's task: in Python 3.11
    a TaskGroup can leave its parent's cancellation count raised.)"""
    task = asyncio.current_task()
    if task is not None and task.cancelling():
        raise asyncio.CancelledError


def _describe(exc: BaseException) -> str:
    if isinstance(exc, BaseExceptionGroup):
        return "; ".join(_describe(e) for e in exc.exceptions)
    return f"{type(exc).__name__}: {exc}"[:200]
