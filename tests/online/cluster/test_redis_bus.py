"""The Redis bus (posecast.online.cluster.redis_bus) in process, against a real
``redis-server`` (the fixture of ``tests/system/scaleout/conftest.py``), with a recording
sink in place of the hub: the ordering of its writes and reads, exactly.

A node ends a local player's session when a read lists the player on another live
node (a takeover whose ``join`` could not cross, e.g. during a Redis outage), but
only on a read issued after the node's own entry for the player was written: an
older read is stale, and the player may have just moved here.
"""

from __future__ import annotations

import asyncio
import contextlib
import time
from collections.abc import Awaitable, Callable, Collection, Mapping, Sequence
from typing import Any

import pytest
import redis
from redis.asyncio import Redis

from posecast.online.cluster.redis_bus import RedisBus
from posecast.online.cluster.redis_store import RedisStore
from posecast.online.metrics import Metrics
from posecast.online.protocol.pose_out import PoseOut
from tests.online.conftest import make_cfg
from tests.system.scaleout.conftest import (  # noqa: F401 - fixtures used by name
    RedisServer,
    redis_server,
    redis_server_bin,
)

pytestmark = pytest.mark.timeout(300)  # the first test may apt-get install redis-server
MEMBERS = "posecast:members:{r1}"


class Sink:
    """A hub stand-in: its local players, and every snapshot the bus reports."""

    def __init__(self) -> None:
        self.local: dict[str, dict[str, str]] = {}
        self.snapshots: list[tuple[str, dict[str, tuple[str, str]], list[str]]] = []
        self.calls = 0  # of local_rooms()
        self.on_call: Callable[[], None] | None = None  # run once, at the next call

    def remote_join(self, room: str, player: str, name: str, node: str, now: float) -> None:
        pass

    def remote_leave(self, room: str, player: str, node: str, now: float) -> None:
        pass

    def remote_tick(
        self,
        room: str,
        node: str,
        poses: Sequence[PoseOut],
        events: Sequence[bytes],
        now: float,
    ) -> None:
        pass

    def remote_snapshot(
        self,
        room: str,
        live: Mapping[str, tuple[str, str]],
        issued_at: float,
        now: float,
        keep: bool = False,
        replaced: Collection[str] = (),
    ) -> None:
        self.snapshots.append((room, dict(live), list(replaced)))

    def remote_lost(self, now: float) -> None:
        pass

    def remote_burn(self, jti: str, exp: int, now: float) -> None:
        pass

    def local_rooms(self) -> dict[str, dict[str, str]]:
        self.calls += 1
        hook, self.on_call = self.on_call, None
        if hook is not None:
            hook()
        return {room: dict(players) for room, players in self.local.items()}


async def stop(bus: RedisBus) -> None:
    """``bus.stop()``; should a task of the bus outlive its cancellation (the failure
    the last test is about), cancel every task again rather than hang the test."""
    stopping = asyncio.ensure_future(bus.stop())
    if not (await asyncio.wait({stopping}, timeout=10))[0]:
        for task in asyncio.all_tasks() - {stopping, asyncio.current_task()}:
            task.cancel()
        await stopping


def run_bus(bus: RedisBus, steps: Callable[[], Awaitable[None]]) -> None:
    """Start ``bus``, run ``steps``, stop it (see :func:`stop`)."""

    async def scenario() -> None:
        await bus.start()
        try:
            await steps()
        finally:
            await stop(bus)

    asyncio.run(scenario())


def px_on_node_f(redis_server: RedisServer) -> tuple[redis.Redis, RedisBus, Sink]:  # noqa: F811
    """Redis (a client of it) where player px of room r1 plays on node-f, which still
    looks alive (its key has not expired); and node-n's bus, not started, with one
    heartbeat only (at the connect): nothing else reads or claims meanwhile."""
    store = redis.Redis(port=redis_server.port)
    store.set("posecast:node:node-f", b"1", px=60_000)
    store.hset(MEMBERS, "px", "node-f\tPX")
    cfg = make_cfg(redis_url=redis_server.url, redis_heartbeat_s=30, redis_node_ttl_s=60)
    bus, sink = RedisBus(cfg, Metrics(), node="node-n"), Sink()
    bus.attach(sink)
    return store, bus, sink


async def until(what: str, check: Callable[[], bool], timeout_s: float = 15.0) -> None:
    deadline = time.monotonic() + timeout_s
    while not check():
        assert time.monotonic() < deadline, f"not in {timeout_s} s: {what}"
        await asyncio.sleep(0.01)


def test_a_stale_read_never_ends_a_local_player_and_a_takeover_does(
    redis_server: RedisServer,  # noqa: F811
) -> None:
    store, bus, sink = px_on_node_f(redis_server)

    async def read_r1() -> tuple[str, dict[str, tuple[str, str]], list[str]]:
        seen = len(sink.snapshots)
        bus.watch("r1")  # (again): one read of the room
        await until("a snapshot of r1", lambda: len(sink.snapshots) > seen)
        return sink.snapshots[-1]

    def admit_px() -> None:  # px reconnects here, through the balancer
        sink.local["r1"] = {"px": "PX"}
        bus.joined("r1", "px", "PX")

    async def steps() -> None:
        await until("the connect's heartbeat", lambda: bus.healthy and sink.calls >= 2)
        # px is admitted while a read of r1 is in flight: the read (issued before px's
        # join was queued) still lists px on node-f, and px is local by the time the
        # read is applied. Stale: px stays.
        sink.on_call = admit_px
        assert await read_r1() == ("r1", {"px": ("node-f", "PX")}, [])
        # A read after the join was written: px is this node's.
        assert await read_r1() == ("r1", {}, [])
        assert store.hget(MEMBERS, "px") == b"node-n\tPX"
        # Node g takes px over while its join cannot reach this node: the next read
        # lists px on node-g, after this node's own entry was written. px ends here.
        store.set("posecast:node:node-g", b"1", px=60_000)
        store.hset(MEMBERS, "px", "node-g\tPX")
        assert await read_r1() == ("r1", {"px": ("node-g", "PX")}, ["px"])

    try:
        run_bus(bus, steps)
    finally:
        store.close()


def test_a_heartbeat_reclaims_its_players_but_not_one_another_node_holds(
    redis_server: RedisServer,  # noqa: F811
) -> None:
    """A heartbeat re-asserts this node's players (after Redis lost them, or a reaper
    took this node for dead) but leaves an entry another node wrote since (a newer
    join there); a join that never reached Redis is written over it and announced."""
    store = redis.Redis(port=redis_server.port)
    store.hset(MEMBERS, mapping={"px": "node-g\tPX", "qx": "node-n\tQX", "nx": "node-g\tNX"})

    async def scenario() -> None:
        client = Redis.from_url(redis_server.url)
        ours = RedisStore("posecast", "node-n", 3.0, Metrics())
        await ours.prepare(client)
        local = {"r1": {"px": "PX", "qx": "QX", "rx": "RX", "nx": "NX"}}
        await ours.reconcile(client, [], lambda: local, claim=local, announce={("r1", "nx")})
        await client.aclose()

    try:
        asyncio.run(scenario())
        assert store.hgetall(MEMBERS) == {
            b"px": b"node-g\tPX",  # held by node-g: left to it
            b"qx": b"node-n\tQX",
            b"rx": b"node-n\tRX",  # lost (or reaped): claimed again
            b"nx": b"node-n\tNX",  # announced: a join, written over node-g's entry
        }
        assert 0 < store.pttl(MEMBERS) <= 6000
        assert store.exists("posecast:node:node-n")
    finally:
        store.close()


def test_a_connection_is_given_up_even_if_a_round_trip_swallows_its_cancellation(
    redis_server: RedisServer,  # noqa: F811
) -> None:
    """When one of a connection's tasks fails, the others are cancelled and the bus
    reconnects. The redis client can swallow the cancellation of a task that is in a
    round trip (the round trip returns as if nothing happened); the command task must
    still stop, or the connection is never given up and the node stays "connected" to
    it for ever."""
    store = redis.Redis(port=redis_server.port)
    cfg = make_cfg(redis_url=redis_server.url, redis_heartbeat_s=30, redis_node_ttl_s=60)
    metrics = Metrics()
    bus, sink = RedisBus(cfg, metrics, node="node-n"), Sink()
    bus.attach(sink)
    execute, stuck = bus.store.execute, asyncio.Event()

    async def swallowing(pipe: Any) -> list[Any]:
        out = await execute(pipe)
        if not stuck.is_set():
            stuck.set()
            with contextlib.suppress(asyncio.CancelledError):  # as the client has done
                await asyncio.sleep(3600)  # until the task is cancelled
        return out

    def reconnects() -> float:
        return metrics.value("posecast_bus_reconnects_total")

    async def steps() -> None:
        await until("the connect's heartbeat", lambda: bus.healthy and sink.calls >= 2)
        bus.store.execute = swallowing  # type: ignore[method-assign]
        bus.watch("r1")  # a read: the command task is in a round trip
        await until("a round trip in flight", stuck.is_set)
        store.client_kill_filter(_type="pubsub")  # the listener fails
        await until("a new connection", lambda: reconnects() >= 2)
        assert bus.healthy

    try:
        run_bus(bus, steps)
    finally:
        store.close()


def test_burned_tokens_are_read_back_through_the_verify_leeway(
    redis_server: RedisServer,  # noqa: F811
) -> None:
    """A node (re)connecting reads the cluster's burned tokens: one past its ``exp`` but
    within ``token_leeway_s`` still passes verification, so it must still be read back
    (and the bus's own record of burns must keep it for its write-back)."""
    store = RedisStore("posecast", "node-n", 60.0, Metrics())
    wall = time.time()
    redis.Redis(port=redis_server.port).zadd(
        store.burned_key, {"late": int(wall) - 2, "gone": int(wall) - 300}
    )

    async def read(leeway_s: float) -> list[str]:
        client = Redis(port=redis_server.port)
        try:
            return [jti for jti, _ in await store.burns(client, 10, leeway_s)]
        finally:
            await client.aclose()

    assert asyncio.run(read(60.0)) == ["late"]
    assert asyncio.run(read(0.0)) == []  # and the zero-leeway read forgot it

    bus = RedisBus(make_cfg(redis_url=redis_server.url, token_leeway_s=60.0), Metrics(), "n")
    bus.burned("late2", int(time.time()) - 2)
    bus.burned("gone2", int(time.time()) - 300)
    assert list(bus._own.live(time.time())) == ["late2"]
