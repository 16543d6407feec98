"""The range of every numeric server setting (:data:`BOUNDS`), in one table.

:class:`~posecast.online.config.ServerConfig` checks each value against it,
``posecast serve --help`` prints each range, and ``docs/server.md`` states each in
its row (a test keeps them alike).
"""

from __future__ import annotations

from dataclasses import dataclass

from posecast.online.engine.config import MAX_SAMPLES
from posecast.online.engine.ports import MAX_THREADS
from posecast.online.protocol.messages import LIMIT_RANGES, MAX_LOOKAHEAD_FRAMES

MAX_SNDBUF_BYTES = 2**31 - 1  # SO_SNDBUF is a C int

# The config's settings that are protocol limits (welcome.limits), by their Limits name.
_LIMITS = {
    "max_message_bytes": "max_message_bytes",
    "max_rate_hz": "max_rate_hz",
    "max_players_per_room": "max_players",
    "max_watch_rooms": "max_watch_rooms",
}
MILLION = 1_000_000


@dataclass(frozen=True)
class Bounds:
    """The range of a numeric setting: ``low`` to ``high``, ``low`` itself excluded
    when ``above``. Every bound is finite, so inf and nan are out of every range."""

    low: float
    high: float
    above: bool = False  # low excluded: a time or a rate, where 0 would stop it
    unit: str = ""

    def holds(self, value: float) -> bool:
        """``value`` is in range (nan never is)."""
        if self.above:
            return self.low < value <= self.high
        return self.low <= value <= self.high

    def interval(self) -> str:
        """For the errors: ``[1, 4096]``, ``(0, 300] seconds``."""
        text = f"{'(' if self.above else '['}{_num(self.low)}, {_num(self.high)}]"
        return f"{text} {self.unit}" if self.unit else text

    def words(self) -> str:
        """For ``--help`` and docs/server.md: ``1 to 4096``, ``above 0, up to 300``."""
        low, high = _num(self.low, True), _num(self.high, True)
        return f"above {low}, up to {high}" if self.above else f"{low} to {high}"


def _num(x: float, commas: bool = False) -> str:
    """``4096``; with ``commas``, a number of six digits or more as ``1,000,000``."""
    if float(x).is_integer():
        return f"{int(x):,}" if commas and x >= 100_000 else str(int(x))
    return f"{x:g}"


def _seconds(high: float) -> Bounds:
    return Bounds(0, high, above=True, unit="seconds")


# Every numeric setting's range (docs/server.md states each in its row, a test keeps
# them alike). The highs are far past any real deployment but keep each guard a guard:
# a token leeway of inf let every token live for ever, a rate of inf turned its limit
# off. Counts of connections and per-IP budgets go to a million (docker-compose.yml
# opens the per-IP ones that far for a load test from one address).
BOUNDS: dict[str, Bounds] = {
    "port": Bounds(0, 65535),
    # Kerberos' default clock skew: past it, a clock is broken, not skewed.
    "token_leeway_s": _seconds(300),
    "replay_cache": Bounds(1, 10 * MILLION),
    "token_keys_reload_s": Bounds(0, 86400, unit="seconds"),  # 0: on SIGHUP only
    "tick_hz": Bounds(1, 240),
    "samples": Bounds(1, MAX_SAMPLES),
    "lookahead": Bounds(0, MAX_LOOKAHEAD_FRAMES, unit="frames"),  # welcome.lookahead_frames
    "wrist_elbow": Bounds(0, 1),
    "engine_threads": Bounds(1, MAX_THREADS),
    "frame_queue": Bounds(1, 256),
    **{name: Bounds(*LIMIT_RANGES[limit]) for name, limit in _LIMITS.items()},
    "rate_burst": Bounds(1, MILLION),
    "control_rate_hz": Bounds(0, MILLION, above=True),
    "error_rate_hz": Bounds(0, MILLION, above=True),
    "max_watchers_per_room": Bounds(1, MILLION),
    "max_rooms": Bounds(1, MILLION),
    "max_connections": Bounds(1, MILLION),
    "conn_per_ip_per_min": Bounds(1, MILLION),
    "sockets_per_ip": Bounds(1, MILLION),
    "fatal_per_ip_per_min": Bounds(1, MILLION),
    "accepts_per_s": Bounds(0, MILLION, above=True),
    "reliable_queue": Bounds(1, 4096),  # each up to max_message_bytes: 32 MiB a client
    "socket_sndbuf_bytes": Bounds(0, MAX_SNDBUF_BYTES, unit="bytes"),
    "slow_consumer_s": _seconds(60),
    "hello_timeout_s": _seconds(60),
    "idle_timeout_s": _seconds(3600),
    "drain_timeout_s": _seconds(600),
    "close_timeout_s": _seconds(60),
    "redis_heartbeat_s": _seconds(60),
    "redis_node_ttl_s": _seconds(600),  # above the gap (below) of the slowest heartbeat
    "redis_timeout_s": _seconds(60),
    "redis_backoff_max_s": _seconds(300),
}
