"""Choose the bus backend by name, once, from the config (like uvicorn's ``auto``):
``redis`` (``--redis URL``), ``local`` (a worker of ``--workers N``, through its
node's relay) or ``memory`` (one process).

The factory lives here, apart from :mod:`posecast.online.cluster.bus` (the interface)
and the backends, so no backend imports another and nothing imports in a circle.
"""

from __future__ import annotations

from collections.abc import Callable

from posecast.errors import ConfigError
from posecast.online.cluster.bus import Bus, default_node_id
from posecast.online.cluster.local import LocalBus, RelayLink
from posecast.online.cluster.memory import MemoryBus
from posecast.online.config import ServerConfig
from posecast.online.metrics import Metrics


def create_bus(
    cfg: ServerConfig,
    metrics: Metrics,
    clock: Callable[[], float],
    link: RelayLink | None = None,
) -> Bus:
    """The backend ``cfg`` names: Redis when ``redis_url`` is set; else, in a worker of
    ``--workers N`` (``link``: its connection to the node's relay), ``local``; else
    in-memory (one process, one node)."""
    node = cfg.node_id or default_node_id()
    if not cfg.redis_url and link is not None:
        return LocalBus(link, metrics, clock=clock)
    if not cfg.redis_url:
        metrics.bus_connected.set(1)
        return MemoryBus(node=node, clock=clock)
    try:
        from posecast.online.cluster.redis_bus import RedisBus
    except ImportError as exc:  # the serving image installs posecast[redis]
        msg = f"--redis needs the redis client: pip install 'posecast[redis]' ({exc})"
        raise ConfigError(msg) from None
    return RedisBus(cfg, metrics, node=node)
