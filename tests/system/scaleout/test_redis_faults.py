"""Redis faults beyond a stopped or hung process (docs/scale-out.md, *Failure behaviour*):
a pub/sub connection that goes silent, a slow Redis, and what a node could not send
while Redis was away (burned tokens, a player that moved meanwhile).

Real ``redis-server`` and ``posecast serve --redis`` processes, as in
``test_two_nodes.py``; the silent and slow connections go through the TCP proxy of
``tests/system/scaleout/redis_proxy.py``. Every wait polls a state the servers report
(``/metrics``, ``/readyz``, Redis itself, the messages a client got) with a generous
deadline: nothing here depends on how fast a loaded machine is.
"""

from __future__ import annotations

import asyncio
import time

import pytest
import redis

from posecast.online.protocol.messages import Bye, Error, Presence, Welcome
from tests.online.conftest import token
from tests.online.wsclient import Client
from tests.system.scaleout.conftest import (
    HEARTBEAT_S,
    NODE_TTL_S,
    Node,
    RedisServer,
    player,
    pose_from,
    run,
    until,
)
from tests.system.scaleout.redis_proxy import RedisProxy

# Generous: the first test may also install redis-server with apt-get (session fixture).
pytestmark = pytest.mark.timeout(300)


def start(*nodes: Node) -> None:
    for n in nodes:
        n.wait_ready()


def test_a_silently_dead_pubsub_connection_is_given_up_and_replaced(
    redis_server: RedisServer, redis_proxy: RedisProxy
) -> None:
    """Node A's pub/sub connection stops passing anything, both ways, without closing
    (its command connection keeps working, so every round trip succeeds). A hears
    nothing from the other nodes until it notices: it PINGs a connection that has been
    quiet for a heartbeat and gives it up when no answer comes within
    ``redis_timeout_s``, then reconnects. Before the fix it never noticed."""
    a, b = Node("node-a", redis_proxy.url), Node("node-b", redis_server.url)
    try:
        start(a, b)

        async def scenario() -> None:
            pa, pb = await player(a, "pa"), await player(b, "pb", seed=1)
            await pa.wait_for(pose_from("pb"), 10)
            reconnects = a.metric("posecast_bus_reconnects_total")
            assert redis_proxy.freeze(pubsub=True) == 1
            await until(
                "node A gave up its silent pub/sub connection",
                lambda: a.metric("posecast_bus_reconnects_total") > reconnects,
            )
            # The new connection carries B's poses again.
            await pa.wait_for(pose_from("pb"), 10, len(pa.messages))
            assert a.http("/readyz")[0] == 200
            for cl in (pa, pb):
                await cl.close()

        run(scenario())
    finally:
        for n in (a, b):
            n.close()


def test_a_node_key_outlives_a_burst_of_room_reads_on_a_slow_redis(
    redis_server: RedisServer, redis_proxy: RedisProxy
) -> None:
    """Node A reaches Redis with 0.15 s round trips (slow, well within
    ``redis_timeout_s``), and spectators open 16 rooms on it at once. Each new room is
    read when it is watched and again when its subscription is confirmed, one round
    trip each: over 4.8 s of reads ahead of the next heartbeat, more than the 3 s node
    TTL. The round trips themselves refresh the node key, so it never lapses and B
    never takes A's player for dead. Before the fix only the heartbeat refreshed it:
    the key expired and B announced A's player gone."""
    rooms, round_trip_s = 16, 0.15
    a, b = Node("node-a", redis_proxy.url), Node("node-b", redis_server.url)
    events = redis.Redis(port=redis_server.port)
    expired = events.pubsub()
    try:
        start(a, b)
        events.config_set("notify-keyspace-events", "Ex")
        expired.subscribe("__keyevent@0__:expired")

        async def scenario() -> None:
            pa, pb = await player(a, "pa"), await player(b, "pb", seed=1)
            await pb.wait_for(pose_from("pa"), 10)
            reconnects = a.metric("posecast_bus_reconnects_total")
            trips = a.metric("posecast_bus_roundtrip_seconds_count")
            redis_proxy.delay_s = round_trip_s / 2
            start_b = len(pb.messages)
            watchers = []
            for i in range(rooms):
                w = await Client.open(a.port)
                tok = token(f"s{i}", f"w{i}", role="spectator")
                assert isinstance(await w.hello(tok, room=f"s{i}", name="W"), Welcome)
                watchers.append(w)
            # Round trips are sequential, 0.15 s or more each: by then every room has
            # been read twice, and the last heartbeat's key would have expired.
            await until(
                "node A read every new room twice",
                lambda: a.metric("posecast_bus_roundtrip_seconds_count") >= trips + 2 * rooms + 6,
                timeout_s=40,
            )
            gone = []  # every key Redis expired meanwhile (and the subscription's reply)
            while (m := expired.get_message(timeout=0.2)) is not None:
                gone.append(m["data"])
            assert b"posecast:node:node-a" not in gone, "node A's key lapsed"
            assert Presence("leave", "r1", "pa", "PA") not in pb.messages[start_b:]
            # The round trips were slow but none failed.
            assert a.metric("posecast_bus_reconnects_total") == reconnects
            redis_proxy.delay_s = 0.0
            for cl in (pa, pb, *watchers):
                await cl.close()

        run(scenario())
    finally:
        expired.close()
        events.close()
        for n in (a, b):
            n.close()


async def bye_session(node: Node, tok: str) -> None:
    cl = await Client.open(node.port)
    assert isinstance(await cl.hello(tok, room="r9", name="U"), Welcome)
    await cl.send(Bye("done"))
    await cl.wait_for(lambda m: isinstance(m, Bye))
    await cl.close()


async def refused(node: Node, tok: str, timeout_s: float = 15.0) -> None:
    """Until ``node`` refuses ``tok`` as burned (a hello it accepts is closed again:
    a connection that merely drops burns nothing)."""
    deadline = time.monotonic() + timeout_s
    while True:
        cl = await Client.open(node.port)
        m = await cl.hello(tok, room="r9", name="U")
        await cl.close()
        if isinstance(m, Error):
            assert m.code == "UNAUTHENTICATED", m
            return
        assert time.monotonic() < deadline, f"{node.name} still accepts a burned token"
        await asyncio.sleep(0.2)


def test_burned_tokens_survive_a_redis_outage_and_an_empty_restart(
    nodes: tuple[Node, Node], redis_server: RedisServer
) -> None:
    """A token burned on B before Redis restarts empty, and one burned on B while Redis
    is down, are refused on A and on a node C that starts afterwards: on reconnecting,
    a node writes back every burn it knows and announces its own again. Before the fix
    the first was lost with Redis's data and the second never left B."""
    a, b = nodes
    c: Node | None = None

    async def scenario() -> None:
        nonlocal c
        before = token("r9", "u1")
        await bye_session(b, before)
        await until(
            "node A heard of the burn",
            lambda: a.metric("posecast_bus_messages_total", direction="in", kind="burn") >= 1,
        )
        await asyncio.to_thread(redis_server.stop)
        await until("node B noticed the outage", lambda: b.http("/readyz")[0] == 503)
        during = token("r9", "u2")
        await bye_session(b, during)
        await asyncio.to_thread(redis_server.start)  # same port, empty
        await asyncio.to_thread(a.wait_ready, 15)
        await asyncio.to_thread(b.wait_ready, 15)
        await refused(a, before)  # A heard it before the outage
        await refused(a, during)
        c = Node("node-c", redis_server.url)
        await asyncio.to_thread(c.wait_ready)
        await refused(c, before)
        await refused(c, during)

    try:
        run(scenario())
    finally:
        if c is not None:
            c.close()


def test_a_player_that_moved_during_a_redis_outage_ends_up_on_one_node(
    nodes: tuple[Node, Node], redis_server: RedisServer
) -> None:
    """Player px plays on A; Redis goes down; px reconnects through B while its old
    connection to A lingers (B's join cannot reach A). When Redis is back, B announces
    the join it could not send, A ends its session with ``REPLACED`` (as the join would
    have online), and Redis says px plays on B. Before the fix both nodes kept a session
    of px and re-asserted it in turn, for good."""
    a, b = nodes
    store = redis.Redis(port=redis_server.port)

    def owner() -> str:
        try:
            value = store.hget("posecast:members:{r1}", "px")
        except redis.ConnectionError:
            return ""
        return value.decode().split("\t")[0] if value else ""

    async def scenario() -> None:
        old, pb = await player(a, "px"), await player(b, "pb", seed=1)
        await pb.wait_for(pose_from("px"), 10)
        await asyncio.to_thread(redis_server.stop)
        for n in (a, b):
            await until(f"{n.name} noticed the outage", lambda n=n: n.http("/readyz")[0] == 503)
        new = await player(b, "px", seed=2)
        await asyncio.to_thread(redis_server.start)  # same port, empty
        err = await old.error(timeout=NODE_TTL_S + 15)
        assert err.code == "REPLACED", err
        await asyncio.wait_for(old.closed.wait(), 5)
        await until("px plays on B in Redis", lambda: owner() == "node-b")
        await asyncio.sleep(HEARTBEAT_S * 2)  # the next heartbeats change nothing
        assert owner() == "node-b"
        assert not new.closed.is_set()
        assert not [m for m in new.messages if isinstance(m, Error)]
        await new.wait_for(pose_from("px"), 5, len(new.messages))
        for cl in (new, pb):
            await cl.close()

    try:
        run(scenario())
    finally:
        store.close()
