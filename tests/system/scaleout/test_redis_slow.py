"""A Redis slow to answer, but within ``redis_timeout_s`` (docs/scale-out.md, *A slow
Redis*): cross-node poses keep flowing at one batch per round trip, and the ordering
the heartbeat's resync relies on holds when the round trips are long.

The slow Redis is the TCP proxy of ``tests/system/scaleout/redis_proxy.py`` with a delay each
way. The figures compared are the servers' own counters (round trips of the sending
node, tick batches heard by the receiving one), as ratios with a wide margin: nothing
here depends on how fast a loaded machine is.
"""

from __future__ import annotations

import asyncio
import itertools

import pytest

from posecast.online.protocol.messages import Pose
from tests.online.cluster.test_redis_bus import MEMBERS, px_on_node_f, run_bus
from tests.system.scaleout.conftest import Node, RedisServer, player, pose_from, run, until
from tests.system.scaleout.redis_proxy import RedisProxy

pytestmark = pytest.mark.timeout(300)  # the first test may apt-get install redis-server

TICKS_IN = "posecast_bus_messages_total"
TRIPS = "posecast_bus_roundtrip_seconds_count"
RECONNECTS = "posecast_bus_reconnects_total"


def gaps(times: list[float]) -> list[float]:
    return [b - a for a, b in itertools.pairwise(times)]


def test_tick_batches_keep_flowing_while_heartbeats_resync_on_a_slow_redis(
    redis_server: RedisServer, redis_proxy: RedisProxy
) -> None:
    """Node B reaches Redis with 0.6 s round trips (slow, well within its
    ``redis_timeout_s`` of 2 s here, with the TTL that timeout needs). A heartbeat's
    resync is two round trips (claim and read, then the liveness check), 1.2 s, longer
    than the 1 s heartbeat: a new resync is queued before each ends. B's player's poses
    must still reach node A at one tick batch per round trip of B (each round trip
    carries the latest batch). Before the fix, pose batches went out only once no
    resync was queued: never, here, and A heard nothing from B for as long as Redis
    stayed that slow."""
    round_trip_s, trips_measured = 0.6, 12
    slow = ("--redis-timeout-s", "2", "--redis-node-ttl-s", "5")
    a, b = Node("node-a", redis_server.url), Node("node-b", redis_proxy.url, *slow)
    try:
        for n in (a, b):
            n.wait_ready()

        async def scenario() -> None:
            pa, pb = await player(a, "pa"), await player(b, "pb", seed=1)
            await pa.wait_for(pose_from("pb"), 10)
            reconnects = b.metric(RECONNECTS)
            redis_proxy.delay_s = round_trip_s / 2
            # Let the round trips started before the delay end, and the slow ones settle.
            await asyncio.sleep(3 * round_trip_s)
            trips0 = b.metric(TRIPS)
            heard0 = a.metric(TICKS_IN, direction="in", kind="tick")
            seen0 = len(pa.messages)
            await until(
                f"node B made {trips_measured} round trips",
                lambda: b.metric(TRIPS) >= trips0 + trips_measured,
                timeout_s=60,
            )
            trips = b.metric(TRIPS) - trips0
            heard = a.metric(TICKS_IN, direction="in", kind="tick") - heard0
            arrived = [m.t for m in pa.messages[seen0:] if isinstance(m, Pose) and m.player == "pb"]
            longest = max(gaps(arrived), default=float("inf"))
            # The round trips were slow but none failed.
            assert b.metric(RECONNECTS) == reconnects
            # One batch per round trip by design; half of that leaves room for a loaded
            # machine (a batch in flight at either end of the window, a tick skipped).
            assert heard >= trips / 2, (
                f"node A heard {heard:.0f} tick batches of node B over {trips:.0f} of B's "
                f"round trips; pose gaps at A up to {longest:.2f} s"
            )
            assert len(arrived) >= trips / 4, f"{len(arrived)} poses of pb reached A's client"
            redis_proxy.delay_s = 0.0
            for cl in (pa, pb):
                await cl.close()

        run(scenario())
    finally:
        for n in (a, b):
            n.close()


def test_a_join_queued_behind_a_resync_is_not_taken_as_written_before_its_reads(
    redis_server: RedisServer,
) -> None:
    """The bus in process (as in ``tests/online/cluster/test_redis_bus.py``). Player px
    played on node-f, which still looks alive, and reconnects here while a resync of
    its room is in progress, just after the next resync was queued: px's join is
    queued behind that resync, whose read still lists px on node-f. On a slow Redis a
    round trip is nearly always in flight, so a join often waits behind a queued
    resync. The read predates px's join, so it must not end px (``replaced``). Before
    the fix a resync counted every join numbered before it was dequeued as written
    ahead of its reads, and reported px replaced: the node would have ended the new
    session and kept none."""
    store, bus, sink = px_on_node_f(redis_server)

    def resync_then_admit_px() -> None:  # run mid-resync, by its read of who is local
        bus.watch("r1")  # queues a resync of r1
        sink.local["r1"] = {"px": "PX"}
        bus.joined("r1", "px", "PX")  # queued behind it

    async def steps() -> None:
        await until("the connect's heartbeat", lambda: bus.healthy and sink.calls >= 2)
        sink.on_call = resync_then_admit_px
        bus.watch("r1")
        await until("px's join written", lambda: store.hget(MEMBERS, "px") == b"node-n\tPX")
        seen = len(sink.snapshots)
        bus.watch("r1")  # one read after the join: px is this node's
        await until("a read after the join", lambda: len(sink.snapshots) > seen)
        stale = [s for s in sink.snapshots if s[1].get("px") == ("node-f", "PX")]
        assert len(stale) >= 2, sink.snapshots  # the resync in progress, and the one queued
        assert all(replaced == [] for _, _, replaced in sink.snapshots), sink.snapshots
        assert sink.snapshots[-1] == ("r1", {}, [])

    try:
        run_bus(bus, steps)
    finally:
        store.close()
