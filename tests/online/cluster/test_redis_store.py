"""What posecast keeps in Redis and the commands it sends (posecast.online.cluster.redis_store),
against a real ``redis-server`` (the fixture of ``tests/system/scaleout/conftest.py``): member
entries owned by their node, reaping a dead node's, the burned set, and a round trip's deadline."""

from __future__ import annotations

import asyncio
import contextlib
import time

import pytest
from redis.asyncio import Redis

from posecast.online.cluster.redis_store import RedisStore
from posecast.online.metrics import Metrics
from tests.system.scaleout.conftest import (  # noqa: F401 - fixtures used by name
    RedisServer,
    redis_server,
    redis_server_bin,
)

pytestmark = pytest.mark.timeout(300)  # the first test may apt-get install redis-server


def test_a_round_trip_whose_replies_trickle_in_fails_at_the_timeout(
    redis_server: RedisServer,  # noqa: F811
) -> None:
    """The client's socket timeout bounds each read, so replies that come in parts,
    each within it, stretched one round trip past ``redis_timeout_s`` with no error
    (1.35 s at a 1 s timeout): the node-key bound (docs/scale-out.md, "A slow Redis")
    assumes none does. The store's own deadline fails it, and the bus reconnects."""

    async def scenario() -> float:
        writers: list[asyncio.StreamWriter] = []
        tasks: list[asyncio.Task[None]] = []

        async def pump(r: asyncio.StreamReader, w: asyncio.StreamWriter, parts: int) -> None:
            with contextlib.suppress(OSError):
                while data := await r.read(65536):
                    k = max(1, len(data) // parts)
                    for i in range(parts):  # a reply in parts, 0.2 s apart
                        if parts > 1:
                            await asyncio.sleep(0.2)
                        w.write(data[i * k : None if i == parts - 1 else (i + 1) * k])
                        await w.drain()

        async def relay(r: asyncio.StreamReader, w: asyncio.StreamWriter) -> None:
            ur, uw = await asyncio.open_connection("127.0.0.1", redis_server.port)
            writers.extend((w, uw))
            tasks.extend((asyncio.create_task(pump(r, uw, 1)), asyncio.create_task(pump(ur, w, 3))))

        proxy = await asyncio.start_server(relay, "127.0.0.1", 0)
        port = proxy.sockets[0].getsockname()[1]
        client = Redis.from_url(f"redis://127.0.0.1:{port}/0", socket_timeout=5.0)  # per read
        store = RedisStore("posecast", "node-x", 3.0, Metrics(), 0.5, timeout_s=0.5)
        try:
            pipe = client.pipeline(transaction=False)
            pipe.hgetall("posecast:members:{r1}")
            t0 = time.perf_counter()
            with pytest.raises(TimeoutError):
                await store.execute(pipe)
            return time.perf_counter() - t0
        finally:
            await client.aclose()
            proxy.close()
            for task in tasks:
                task.cancel()
            await asyncio.gather(*tasks, return_exceptions=True)
            for w in writers:
                w.close()
                with contextlib.suppress(OSError):
                    await w.wait_closed()
            await proxy.wait_closed()

    took = asyncio.run(scenario())
    assert took < 1.5  # three parts 0.2 s apart, each in time: 0.6 s and more without it


def test_entries_belong_to_their_node_and_a_dead_nodes_are_reaped(
    redis_server: RedisServer,  # noqa: F811
) -> None:
    """A join writes ``NODE<TAB>NAME`` under the room's hash tag; a leave sent for a node
    that no longer owns the entry (the player moved) keeps it; a reconcile returns the
    live other nodes' players, deletes the entries of a node whose key is gone and
    announces each leave."""
    metrics = Metrics()
    a = RedisStore("pc", "node-a", 60.0, metrics)
    b = RedisStore("pc", "node-b", 60.0, Metrics())
    assert a.members_key("r1") == "pc:members:{r1}" and a.channel("r1") == "pc:room:{r1}"
    assert a.node_key("node-a") == "pc:node:node-a"

    async def scenario() -> tuple[dict[bytes, bytes], dict[bytes, bytes], dict, dict]:
        client = Redis.from_url(redis_server.url)
        try:
            for store in (a, b):
                await store.prepare(client)
            pipe = client.pipeline(transaction=False)
            a.join(pipe, "r1", "p1", "Ann")
            b.join(pipe, "r1", "p2", "Bo")
            await a.execute(pipe)  # refreshes node-a's key with the round trip
            pipe = client.pipeline(transaction=False)
            b.refresh(pipe)
            a.leave(pipe, "r1", "p2", "node-a")  # node-a does not own p2: kept
            await b.execute(pipe)
            joined = await client.hgetall("pc:members:{r1}")
            seen_by_a = await a.reconcile(client, ["r1"], lambda: {"r1": {"p1": "Ann"}})
            await client.delete("pc:node:node-b")  # node-b died
            after = await a.reconcile(client, ["r1"], lambda: {"r1": {"p1": "Ann"}})
            left = await client.hgetall("pc:members:{r1}")
            return joined, left, seen_by_a, after
        finally:
            await client.aclose()

    joined, left, seen_by_a, after = asyncio.run(scenario())
    assert joined == {b"p1": b"node-a\tAnn", b"p2": b"node-b\tBo"}
    assert seen_by_a == {"r1": {"p2": ("node-b", "Bo")}}  # node-a's own are not listed
    assert after == {"r1": {}}
    assert left == {b"p1": b"node-a\tAnn"}  # p2's entry reaped with its node
    assert metrics.value("posecast_bus_messages_total", {"direction": "out", "kind": "leave"}) == 2


def test_burns_are_read_back_until_they_expire(
    redis_server: RedisServer,  # noqa: F811
) -> None:
    """A burned token id is in the burned set with its expiry until it passes, then it is
    forgotten (removed from the set) on the next read."""
    store = RedisStore("pc", "node-a", 60.0, Metrics())
    now = int(time.time())

    async def scenario() -> tuple[list[tuple[str, int]], list[bytes]]:
        client = Redis.from_url(redis_server.url)
        try:
            pipe = client.pipeline(transaction=False)
            store.burn(pipe, "live", now + 300)
            store.burn(pipe, "old", now - 300)
            await store.execute(pipe)
            found = await store.burns(client, 10)
            return found, await client.zrange("pc:burned", 0, -1)
        finally:
            await client.aclose()

    found, kept = asyncio.run(scenario())
    assert found == [("live", now + 300)]
    assert kept == [b"live"]
