"""A node of two workers on Redis (``posecast serve --workers 2 --redis URL``): each
worker is a node of the Redis bus (``NODE-w0``, ``NODE-w1``), so one room spans the
node's two workers and another node (docs/scale-out.md, Workers)."""

from __future__ import annotations

import pytest
import redis

from posecast.online.protocol.messages import Welcome
from tests.online.conftest import token
from tests.system.scaleout.conftest import Node, RedisServer, player, pose_from, run
from tests.system.test_workers import placed

pytestmark = pytest.mark.timeout(300)  # the first test may apt-get install redis-server


def test_a_room_spans_two_workers_of_one_node_and_another_node(
    redis_server: RedisServer,
) -> None:
    a = Node("node-a", redis_server.url, "--workers", "2")
    b = Node("node-b", redis_server.url)
    try:
        a.wait_ready()
        b.wait_ready()
        keys = redis.Redis.from_url(redis_server.url).keys("posecast:node:*")
        assert {k.decode() for k in keys} == {
            "posecast:node:node-a-w0",
            "posecast:node:node-a-w1",
            "posecast:node:node-b",
        }

        async def scenario() -> None:
            on = await placed(a.port)
            for w, cl in on.items():
                name = f"a{w}"
                welcome = await cl.hello(token("r1", name), room="r1", name=name.upper())
                assert isinstance(welcome, Welcome)
                cl.stream(seed=int(w))
            pb = await player(b, "b", seed=5)
            everyone = {"a0": on["0"], "a1": on["1"], "b": pb}
            for cl in everyone.values():
                for other in everyone:
                    await cl.wait_for(pose_from(other), 20)
            m = a.metrics()  # one scrape, both workers: each hosts one, sees two elsewhere
            for w in ("0", "1"):
                assert m[f'posecast_players{{worker="{w}"}}'] == 1
                assert m[f'posecast_remote_players{{worker="{w}"}}'] == 2
            for cl in everyone.values():
                await cl.close()

        run(scenario())
    finally:
        b.close()
        a.close()
