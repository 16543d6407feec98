"""What posecast keeps in Redis, and every command it sends there.

Keys and channels (``prefix`` is ``redis_prefix``; ``{room}`` is a Redis Cluster
hash tag, so a room's hash and channel live in one slot)::

    prefix:node:NODE          string, PX node_ttl     the node's heartbeat
    prefix:members:{ROOM}     hash player -> "NODE\\tNAME", PX 2 x node_ttl
    prefix:room:{ROOM}        channel: tick, join and leave messages of the room
    prefix:ctl                channel: burn messages (token ids, cluster-wide)
    prefix:burned             sorted set: token id -> expiry (Unix seconds)

A member value is ``node`` and display name separated by a TAB, which neither may
contain (node ids are ``[A-Za-z0-9_.-]``, names have no control characters).
:class:`RedisStore` only builds commands into pipelines and reads replies; the
connection, its tasks and reconnects are :mod:`posecast.online.cluster.redis_bus`'s.
"""

from __future__ import annotations

import asyncio
import time
from collections.abc import Callable, Collection, Mapping
from typing import Any

from redis.asyncio import Redis

from posecast.online.cluster.bus import BusMessage, encode_message
from posecast.online.metrics import Metrics

Members = dict[str, tuple[str, str]]  # player -> (node, name)

# Delete a member entry only if ``node`` still owns it (the player may have moved to
# another node since), then announce the leave; one atomic round trip.
LEAVE_LUA = """
local v = redis.call('HGET', KEYS[1], ARGV[1])
if v and string.sub(v, 1, #ARGV[2] + 1) == ARGV[2] .. '\\t' then
  redis.call('HDEL', KEYS[1], ARGV[1])
end
return redis.call('PUBLISH', ARGV[3], ARGV[4])
"""

# Re-assert this node's players (every heartbeat) without taking an entry that another
# node holds: a join there since (a takeover whose announcement could not cross, e.g.
# during a Redis outage) is newer, and this node ends its own session when it reads it.
# ARGV: node, hash TTL in ms, then player, value pairs.
CLAIM_LUA = """
for i = 3, #ARGV, 2 do
  local v = redis.call('HGET', KEYS[1], ARGV[i])
  if not v or string.sub(v, 1, #ARGV[1] + 1) == ARGV[1] .. '\\t' then
    redis.call('HSET', KEYS[1], ARGV[i], ARGV[i + 1])
  end
end
return redis.call('PEXPIRE', KEYS[1], ARGV[2])
"""
_CHUNK = 1000  # commands per pipeline when re-sending many burns


class RedisStore:
    def __init__(
        self,
        prefix: str,
        node: str,
        node_ttl_s: float,
        metrics: Metrics,
        refresh_every_s: float = 0.5,
        timeout_s: float | None = None,
    ) -> None:
        """``timeout_s``: the longest one round trip of :meth:`execute` may take, as a
        whole (the client's socket timeout bounds each read: replies that trickle in
        could stretch a round trip far past it)."""
        self.prefix, self.node, self.metrics = prefix, node, metrics
        self.ttl_ms = int(node_ttl_s * 1000)
        self.ctl_channel = f"{prefix}:ctl"
        self.burned_key = f"{prefix}:burned"
        self._leave_sha = self._claim_sha = ""
        self.refresh_every_s = refresh_every_s
        self.timeout_s = timeout_s
        # Called with every pipeline about to go out that holds a command: adds what
        # must not wait for a long series of round trips (the bus's pose batches).
        self.piggyback: Callable[[Any], None] | None = None
        self._registered = True  # the node key is ours to refresh (not after goodbye)
        self._refreshed = float("-inf")  # when a round trip last carried the node key

    def channel(self, room: str) -> str:
        return f"{self.prefix}:room:{{{room}}}"

    def members_key(self, room: str) -> str:
        return f"{self.prefix}:members:{{{room}}}"

    def node_key(self, node: str) -> str:
        return f"{self.prefix}:node:{node}"

    async def prepare(self, client: Redis) -> None:
        """Once per connection: load the scripts (a restarted Redis has forgotten them)."""
        self._leave_sha = await client.script_load(LEAVE_LUA)
        self._claim_sha = await client.script_load(CLAIM_LUA)

    # --- writes, queued into a pipeline ------------------------------------------------

    def join(self, pipe: Any, room: str, player: str, name: str) -> None:
        key = self.members_key(room)
        pipe.hset(key, player, f"{self.node}\t{name}")
        pipe.pexpire(key, 2 * self.ttl_ms)
        self.publish(pipe, room, BusMessage("join", self.node, player, name))

    def leave(self, pipe: Any, room: str, player: str, node: str) -> None:
        """``node``'s player left (``node`` is another one when reaping a dead node)."""
        data = self._counted("leave", BusMessage("leave", node, player))
        key, channel = self.members_key(room), self.channel(room)
        pipe.evalsha(self._leave_sha, 1, key, player, node, channel, data)

    def burn(self, pipe: Any, jti: str, exp: int, *, add: bool = True) -> None:
        """Announce a burned token id (and ``add`` it to the burned set)."""
        if add:
            pipe.zadd(self.burned_key, {jti: exp})
        pipe.publish(
            self.ctl_channel, self._counted("burn", BusMessage("burn", self.node, jti, exp=exp))
        )

    def goodbye(self, pipe: Any) -> None:
        self._registered = False
        pipe.delete(self.node_key(self.node))

    def refresh(self, pipe: Any) -> None:
        """Refresh this node's key (its heartbeat)."""
        if self._registered:
            self._refreshed = time.perf_counter()
            pipe.set(self.node_key(self.node), b"1", px=self.ttl_ms)

    def publish(self, pipe: Any, room: str, m: BusMessage) -> None:
        pipe.publish(self.channel(room), self._counted(m.kind, m))

    def _counted(self, kind: str, m: BusMessage) -> bytes:
        data = encode_message(m)
        self.count("out", kind, data)
        return data

    def count(self, direction: str, kind: str, data: bytes) -> None:
        self.metrics.bus_messages.labels(direction, kind).inc()
        self.metrics.bus_bytes.labels(direction).inc(len(data))

    async def execute(self, pipe: Any) -> list[Any]:
        """One round trip; the replies of the commands queued by the caller. Every round
        trip also refreshes the node key when the last refresh is ``refresh_every_s``
        old: a Redis slow but within ``redis_timeout_s`` (a heartbeat's resync is
        several round trips, a burst of room reads after a reconnect many) must not let
        a live node's key lapse. For the same reason it carries what ``piggyback`` adds
        (pose batches must not wait for a resync's round trips)."""
        n = len(pipe)
        if not n:
            return []
        if self.piggyback is not None:
            self.piggyback(pipe)
        t0 = time.perf_counter()
        if t0 - self._refreshed >= self.refresh_every_s:
            self.refresh(pipe)
        async with asyncio.timeout(self.timeout_s):
            out: list[Any] = await pipe.execute()
        took = time.perf_counter() - t0
        self.metrics.bus_roundtrip.observe(took)
        if self.timeout_s is not None and took > self.timeout_s:
            # The client can swallow the timeout's cancellation and return late.
            raise TimeoutError(f"a Redis round trip took {took:.2f} s")
        return out[:n]

    async def reburn(self, client: Redis, known: Mapping[str, int], own: Mapping[str, int]) -> None:
        """After a (re)connect: put back every burn this node knows (a Redis restarted
        empty lost them) and announce its own again (those made while disconnected never
        went out; a repeat is harmless)."""
        known_items, own_items = list(known.items()), list(own.items())
        for i in range(0, len(known_items), _CHUNK):
            pipe = client.pipeline(transaction=False)
            pipe.zadd(self.burned_key, dict(known_items[i : i + _CHUNK]))
            await self.execute(pipe)
        for i in range(0, len(own_items), _CHUNK):
            pipe = client.pipeline(transaction=False)
            for jti, exp in own_items[i : i + _CHUNK]:
                self.burn(pipe, jti, exp, add=False)  # added above
            await self.execute(pipe)

    # --- reads ---------------------------------------------------------------------------

    async def reconcile(
        self,
        client: Redis,
        rooms: list[str],
        local_rooms: Callable[[], Mapping[str, Mapping[str, str]]],
        *,
        claim: Mapping[str, Mapping[str, str]] | None = None,
        announce: Collection[tuple[str, str]] = (),
    ) -> dict[str, Members]:
        """Each room's live members on other nodes in Redis, dead nodes' entries reaped.

        With ``claim`` (a heartbeat: room -> this node's players), first refresh this
        node's key and re-assert those players (all a resync after an outage or a Redis
        restart needs), leaving an entry another node holds to that node (CLAIM_LUA);
        the players in ``announce`` (room, player pairs: joins that never reached
        Redis) are joined instead, written over any entry and announced. Entries of
        nodes whose key expired are deleted and their leave announced, as are this
        node's entries for players no longer here."""
        pipe = client.pipeline(transaction=False)
        if claim is not None:
            self.refresh(pipe)
            for room, players in claim.items():
                pairs = [
                    x
                    for p, n in players.items()
                    if (room, p) not in announce
                    for x in (p, f"{self.node}\t{n}")
                ]
                if pairs:
                    key = self.members_key(room)
                    pipe.evalsha(self._claim_sha, 1, key, self.node, 2 * self.ttl_ms, *pairs)
                for p, n in players.items():
                    if (room, p) in announce:
                        self.join(pipe, room, p, n)
        first = len(pipe)
        for room in rooms:
            pipe.hgetall(self.members_key(room))
        replies = (await self.execute(pipe))[first:]
        tables = {room: _parse(raw) for room, raw in zip(rooms, replies, strict=True)}
        nodes = sorted({n for t in tables.values() for n, _ in t.values()} - {self.node})
        pipe = client.pipeline(transaction=False)
        for n in nodes:
            pipe.exists(self.node_key(n))
        alive = {n for n, up in zip(nodes, await self.execute(pipe), strict=True) if up}
        alive.add(self.node)
        local = local_rooms()  # now, after the reads: who is still here
        pipe = client.pipeline(transaction=False)
        for room, table in tables.items():
            for player, (node, _) in table.items():
                if node not in alive or (node == self.node and player not in local.get(room, {})):
                    self.leave(pipe, room, player, node)  # reaped, and announced
        await self.execute(pipe)
        others = alive - {self.node}
        return {room: {p: v for p, v in t.items() if v[0] in others} for room, t in tables.items()}

    async def burns(
        self, client: Redis, limit: int, leeway_s: float = 0.0
    ) -> list[tuple[str, int]]:
        """Token ids burned and not yet expired, ``leeway_s`` after their ``exp`` as
        tokens are verified (and forget the expired ones)."""
        wall = time.time() - leeway_s
        pipe = client.pipeline(transaction=False)
        pipe.zremrangebyscore(self.burned_key, "-inf", wall)
        pipe.zrangebyscore(self.burned_key, wall, "+inf", start=0, num=limit, withscores=True)
        _, found = await self.execute(pipe)
        return [(jti.decode(), int(exp)) for jti, exp in found]


def _parse(raw: dict[bytes, bytes]) -> Members:
    out = {}
    for player, value in raw.items():
        node, _, name = value.decode("utf-8", "replace").partition("\t")
        out[player.decode("utf-8", "replace")] = (node, name)
    return out
