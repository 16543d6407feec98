"""Two ``posecast serve --redis`` processes on one real Redis (docs/scale-out.md).

Players on node A and node B in one room see each other; a room elsewhere sees
nothing; a SIGKILLed node's player leaves within the documented bound; a Redis
restart costs cross-node traffic for the outage only, never local play.
"""

from __future__ import annotations

import asyncio
import itertools
import re
import signal
import time

import pytest

from posecast.online.protocol.messages import Bye, Error, Pose, Presence, Welcome
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
)

# Generous: the first test may also install redis-server with apt-get (session fixture).
pytestmark = pytest.mark.timeout(300)
# A dead node's players are announced as leaving within NODE_TTL_S + HEARTBEAT_S
# plus a round trip (docs/scale-out.md): its key expires NODE_TTL_S after its last
# heartbeat, and a live node's next heartbeat (at most HEARTBEAT_S later) finds it
# gone. The test allows one second more for a loaded CI machine.
LEAVE_BOUND_S = NODE_TTL_S + HEARTBEAT_S + 1.0


def test_players_on_two_nodes_see_each_other_and_other_rooms_nothing(
    nodes: tuple[Node, Node],
) -> None:
    a, b = nodes

    async def scenario() -> None:
        pa, pb = await player(a, "pa"), await player(b, "pb", seed=1)
        other = await player(b, "pc", room="r2", seed=2)
        await pa.wait_for(pose_from("pb"), 10)
        await pb.wait_for(pose_from("pa"), 10)
        await pa.wait_for(lambda m: m == Presence("join", "r1", "pb", "PB"), 10)
        await asyncio.sleep(0.5)
        assert {p.player for p in pa.poses()} == {"pa", "pb"}
        assert {p.player for p in pb.poses()} == {"pa", "pb"}
        assert {p.player for p in other.poses()} == {"pc"}
        assert not [m for m in other.messages if isinstance(m, Presence)]
        seqs = [p.seq for p in pb.poses("pa")]
        assert seqs == sorted(seqs) and len(seqs) >= 10
        _, metrics = a.http("/metrics")
        assert "posecast_remote_players 1.0" in metrics
        assert 'posecast_bus_messages_total{direction="out",kind="tick"}' in metrics
        await pa.close()
        await pb.wait_for(lambda m: m == Presence("leave", "r1", "pa", "PA"), 10)
        for cl in (pb, other):
            await cl.close()

        # A session that ended with bye burns its token on every node (replay guard).
        tok = token("r2", "pd")
        pd = await Client.open(b.port)
        assert isinstance(await pd.hello(tok, room="r2", name="PD"), Welcome)
        await pd.send(Bye("done"))
        await pd.wait_for(lambda m: isinstance(m, Bye))
        burns_in = 'posecast_bus_messages_total{direction="in",kind="burn"} 1.0'
        deadline = time.monotonic() + 10
        while burns_in not in a.http("/metrics")[1]:  # the burn crosses Redis
            assert time.monotonic() < deadline, "node A never heard of the burn"
            await asyncio.sleep(0.05)
        again = await Client.open(a.port)
        err = await again.hello(tok, room="r2", name="PD")
        assert isinstance(err, Error) and err.code == "UNAUTHENTICATED", err
        for cl in (pd, again):
            await cl.close()

    run(scenario())


def test_sigkilled_node_players_leave_within_the_bound(nodes: tuple[Node, Node]) -> None:
    a, b = nodes

    async def scenario() -> None:
        pa, pb = await player(a, "pa"), await player(b, "pb", seed=1)
        await pa.wait_for(pose_from("pb"), 10)
        t0 = time.monotonic()
        b.kill()
        start = len(pa.messages)
        await pa.wait_for(lambda m: m == Presence("leave", "r1", "pb", "PB"), 10, start)
        took = time.monotonic() - t0
        print(f"leave of a SIGKILLed node's player reached node A after {took:.2f} s")
        assert took <= LEAVE_BOUND_S, (took, LEAVE_BOUND_S)
        assert a.http("/readyz")[0] == 200  # A itself is fine
        await pa.wait_for(pose_from("pa"), 2, len(pa.messages))  # A plays on
        await asyncio.wait_for(pb.closed.wait(), 5)  # its socket died with node B
        for cl in (pa, pb):
            await cl.close()

    run(scenario())


def test_a_draining_node_announces_its_players_leaving_at_once(nodes: tuple[Node, Node]) -> None:
    a, b = nodes

    async def scenario() -> None:
        pa, pb = await player(a, "pa"), await player(b, "pb", seed=1)
        await pa.wait_for(pose_from("pb"), 10)
        t0 = time.monotonic()
        b.proc.send_signal(signal.SIGTERM)
        start = len(pa.messages)
        await pa.wait_for(lambda m: m == Presence("leave", "r1", "pb", "PB"), 10, start)
        took = time.monotonic() - t0
        assert took < 1.5, f"{took:.2f} s: the drain should announce it, not the TTL"
        assert b.proc.wait(timeout=15) == 0
        await asyncio.wait_for(pb.closed.wait(), 5)
        for cl in (pa, pb):
            await cl.close()

    run(scenario())


def test_redis_restart_keeps_local_play_and_recovers_cross_node(
    nodes: tuple[Node, Node], redis_server: RedisServer
) -> None:
    a, b = nodes

    async def scenario() -> None:
        pa, mate = await player(a, "pa"), await player(a, "mate", seed=3)
        pb = await player(b, "pb", seed=1)
        await pa.wait_for(pose_from("pb"), 10)
        redis_server.stop()
        t_down = time.monotonic()
        while a.http("/readyz")[0] != 503:
            assert time.monotonic() - t_down < 5, "node A still ready without Redis"
            await asyncio.sleep(0.05)
        _, body = a.http("/readyz")
        assert "redis" in body, body
        # Local play never stops: pa keeps getting mate's poses through the outage,
        # with no gap longer than a few ticks.
        start = len(pa.messages)
        await asyncio.sleep(NODE_TTL_S + 1.0)  # past the TTL: pb is announced as gone
        local = [m for m in pa.messages[start:] if isinstance(m, Pose) and m.player == "mate"]
        assert len(local) >= 60 * NODE_TTL_S * 0.5, len(local)
        ticks = [p.t for p in local]  # server time of each pose: the tick never stalled
        assert max(t1 - t0 for t0, t1 in itertools.pairwise(ticks)) < 0.5
        assert Presence("leave", "r1", "pb", "PB") in pa.messages[start:]
        assert a.proc.poll() is None and b.proc.poll() is None

        redis_server.start()  # same port, empty: the nodes must re-assert everything
        t_up = time.monotonic()
        start = len(pa.messages)
        await pa.wait_for(lambda m: m == Presence("join", "r1", "pb", "PB"), 15, start)
        await pa.wait_for(pose_from("pb"), 5, start)
        await pb.wait_for(pose_from("pa"), 5, len(pb.messages) - 1)
        print(
            f"cross-node poses flowed again {time.monotonic() - t_up:.2f} s after Redis restarted"
        )
        a.wait_ready(5)
        b.wait_ready(5)
        for cl in (pa, mate, pb):
            await cl.close()

    run(scenario())


def test_a_hung_redis_is_detected_and_the_tick_keeps_time(
    nodes: tuple[Node, Node], redis_server: RedisServer
) -> None:
    """SIGSTOP: Redis's sockets stay open and nothing answers, the silent failure mode.
    A round trip times out after redis_timeout_s (1 s by default)."""
    a, _ = nodes
    assert redis_server.proc is not None

    def ticks() -> float:
        found = re.search(r"^posecast_tick_seconds_count (\S+)$", a.http("/metrics")[1], re.M)
        assert found is not None
        return float(found[1])

    redis_server.proc.send_signal(signal.SIGSTOP)
    try:
        t0 = time.monotonic()
        while a.http("/readyz")[0] == 200:
            assert time.monotonic() - t0 < 1.0 + HEARTBEAT_S + 3, "a hung Redis went unnoticed"
            time.sleep(0.05)
        before, t1 = ticks(), time.monotonic()
        time.sleep(1.0)
        rate = (ticks() - before) / (time.monotonic() - t1)
        assert rate > 50, f"the tick slowed to {rate:.0f} Hz while Redis hung"
    finally:
        redis_server.proc.send_signal(signal.SIGCONT)
    a.wait_ready(10)
