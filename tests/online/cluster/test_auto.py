"""The bus factory (posecast.online.cluster.auto): the backend the config names."""

from __future__ import annotations

import time

import pytest

from posecast.errors import ConfigError
from posecast.online.cluster.auto import create_bus
from posecast.online.cluster.memory import MemoryBus
from posecast.online.metrics import Metrics
from tests.online.conftest import make_cfg


def test_create_bus_picks_the_backend_by_config() -> None:
    m = Metrics()
    bus = create_bus(make_cfg(node_id="n-1"), m, clock=time.monotonic)
    assert isinstance(bus, MemoryBus) and bus.node == "n-1" and bus.healthy
    assert m.value("posecast_bus_connected") == 1
    redis = create_bus(make_cfg(redis_url="redis://127.0.0.1:1/0"), m, clock=time.monotonic)
    assert type(redis).__name__ == "RedisBus" and not redis.healthy
    assert "redis unavailable" in redis.status
    for bad in ({"redis_url": "http://x"}, {"node_id": "a b"}, {"redis_node_ttl_s": 1.0}):
        with pytest.raises(ConfigError):
            make_cfg(**bad)


def test_serve_takes_redis_from_the_flag_or_the_environment() -> None:
    from posecast.cli import build_parser
    from posecast.online.config import ServerConfig

    args = vars(build_parser().parse_args(["serve", "--redis", "redis://r:6379/0"]))
    assert args["redis_url"] == "redis://r:6379/0"
    env = {"POSECAST_TOKEN_SECRET": "s" * 32, "POSECAST_REDIS_URL": "redis://e:6379/0"}
    assert ServerConfig.from_sources(env).redis_url == "redis://e:6379/0"
    assert "redis://" not in repr(ServerConfig.from_sources(env)), "may carry a password"
