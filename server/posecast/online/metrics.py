"""Prometheus metrics of one server instance, on a registry the instance owns.

Not the process-global default registry: two servers in one process (the tests run
many) each count their own, and nothing leaks between them. ``/metrics`` serves
:meth:`Metrics.render`; with ``--workers N`` (N > 1) it serves the whole node's,
every worker's and the supervisor's (:class:`SupervisorMetrics`) joined by
:func:`merge_expositions`, each sample labelled with its ``worker``.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
from collections.abc import Iterator, Sequence

from prometheus_client import CollectorRegistry, Counter, Gauge, Histogram, generate_latest
from prometheus_client.exposition import CONTENT_TYPE_LATEST
from prometheus_client.metrics_core import Metric
from prometheus_client.parser import text_string_to_metric_families

from posecast.online.auth.tokens import REASONS

CONTENT_TYPE = CONTENT_TYPE_LATEST
_TICK_BUCKETS = (0.001, 0.002, 0.004, 0.008, 0.012, 0.0167, 0.025, 0.05, 0.1, 0.25, 1.0)
_BATCH_BUCKETS = (0, 1, 2, 4, 8, 16, 32, 64, 128, 256, 512)
_DRIFT_BUCKETS = (1, 10, 50, 100, 200, 500, 1000, 10_000)
_BUS_BUCKETS = (0.0005, 0.001, 0.002, 0.005, 0.01, 0.025, 0.05, 0.1, 0.25, 1.0)


log = logging.getLogger("posecast.metrics")


class Metrics:
    """Every metric ``posecast serve`` exports (names are ``posecast_*``)."""

    def __init__(self) -> None:
        r = self.registry = CollectorRegistry(auto_describe=True)
        self.connections = Gauge(
            "posecast_connections", "Open WebSocket connections, by role", ["role"], registry=r
        )
        self.players = Gauge("posecast_players", "Players in this node's rooms", registry=r)
        self.rooms = Gauge("posecast_rooms", "Rooms open", registry=r)
        self.connects = Counter(
            "posecast_connects", "Connection attempts, by result", ["result"], registry=r
        )
        self.tick_seconds = Histogram(
            "posecast_tick_seconds",
            "Wall time of one engine tick (engine thread)",
            buckets=_TICK_BUCKETS,
            registry=r,
        )
        self.ticks = Counter("posecast_ticks", "Engine ticks delivered", registry=r)
        self.engine_info = Gauge(
            "posecast_engine_info",
            "1 for each layout's engine: its backend and, on native, the kernels' "
            "instruction-set level and GRU precision (fp32, bf16, bf16-emulated)",
            ["layout", "backend", "isa", "precision"],
            registry=r,
        )
        self.poses = Counter(
            "posecast_poses", "Poses the engine produced and routed to their rooms", registry=r
        )
        self.tick_overruns = Counter(
            "posecast_tick_overruns", "Ticks that started late by a whole period", registry=r
        )
        self.batch_size = Histogram(
            "posecast_engine_batch_size", "Players per engine step", buckets=_BATCH_BUCKETS,
            registry=r,
        )  # fmt: skip
        self.transitions = Counter(
            "posecast_ssi_transitions", "SSI sample transitions started", registry=r
        )
        self.reach_limited = Counter(
            "posecast_reach_limited",
            "Poses sent with the head, a hand or a tracked foot or knee more than 1 mm "
            "from its tracker (out of reach)",
            registry=r,
        )
        self.frames_in = Counter("posecast_frames", "Tracker frames accepted", registry=r)
        self.reads_paced = Counter(
            "posecast_reads_paced",
            "Times a connection's reading paused: it sent faster than its read budget",
            registry=r,
        )
        self.frame_times_odd = Counter(
            "posecast_frame_times_odd",
            "Frames accepted whose t repeats, goes back, or jumps (proto/README.md, Time)",
            ["kind"],
            registry=r,
        )
        self.server_late = Counter(
            "posecast_server_late_seconds",
            "Seconds the timeout checks came late (event loop or tick held up); "
            "the clients' timeouts stop for them",
            registry=r,
        )
        self.floods_cut_off = Counter(
            "posecast_floods_cut_off",
            "Connections cut off (RATE_LIMITED) for staying past their read budget",
            registry=r,
        )
        self.frames_dropped = Counter(
            "posecast_frames_dropped",
            "Tracker frames dropped, by reason",
            ["reason"],
            registry=r,
        )
        self.poses_superseded = Counter(
            "posecast_poses_superseded",
            "Poses replaced in a client's outbox before it could be sent",
            registry=r,
        )
        self.errors = Counter(
            "posecast_errors", "Protocol errors, by wire code", ["code"], registry=r
        )
        self.token_refusals = Counter(
            "posecast_token_refusals",
            "hello tokens refused (UNAUTHENTICATED, TOKEN_EXPIRED), by reason: "
            + ", ".join(REASONS),
            ["reason"],
            registry=r,
        )
        self.key_reloads = Counter(
            "posecast_token_key_reloads",
            "Reloads of the token key set (SIGHUP, interval), by result (ok, failed: the "
            "old set stays)",
            ["result"],
            registry=r,
        )
        self.token_keys = Gauge(
            "posecast_token_keys", "Keys in the token key set in force", registry=r
        )
        self.bytes_in = Counter("posecast_bytes_in", "WebSocket payload bytes in", registry=r)
        self.bytes_out = Counter("posecast_bytes_out", "WebSocket payload bytes out", registry=r)
        self.clock_drift = Histogram(
            "posecast_clock_drift_ppm",
            "Absolute client clock drift at session end, ppm (capped at 10,000)",
            buckets=_DRIFT_BUCKETS,
            registry=r,
        )

        # The bus between nodes (docs/scale-out.md); the embedded node reports connected.
        self.bus_connected = Gauge(
            "posecast_bus_connected", "1 while cross-node traffic flows, else 0", registry=r
        )
        self.bus_reconnects = Counter(
            "posecast_bus_reconnects", "Connections to the bus's store (Redis) made", registry=r
        )
        self.bus_messages = Counter(
            "posecast_bus_messages", "Bus messages, by direction and kind", ["direction", "kind"],
            registry=r,
        )  # fmt: skip
        self.bus_bytes = Counter(
            "posecast_bus_bytes", "Bus message payload bytes, by direction", ["direction"],
            registry=r,
        )  # fmt: skip
        self.bus_dropped = Counter(
            "posecast_bus_dropped",
            "Bus messages not sent or not used, by reason (superseded, disconnected, "
            "unknown_player, undecodable)",
            ["reason"],
            registry=r,
        )
        self.bus_roundtrip = Histogram(
            "posecast_bus_roundtrip_seconds",
            "Wall time of one pipelined round trip to the bus's store",
            buckets=_BUS_BUCKETS,
            registry=r,
        )
        self.remote_players = Gauge(
            "posecast_remote_players", "Players on other nodes in this node's rooms", registry=r
        )
        # For leak checks (benchmarks/load.py): the count should follow the connections
        # and come back to its idle value once they are gone.
        self.asyncio_tasks = Gauge(
            "posecast_asyncio_tasks",
            "asyncio tasks alive in the server's event loop (counted at each /metrics read)",
            registry=r,
        )

    def render(self) -> bytes:
        """The exposition text. Called in the event loop (the ``/metrics`` handler), it
        first counts that loop's tasks; called outside one, it leaves the last count."""
        with contextlib.suppress(RuntimeError):  # no running event loop
            self.asyncio_tasks.set(len(asyncio.all_tasks()))
        out: bytes = generate_latest(self.registry)
        return out

    def value(self, name: str, labels: dict[str, str] | None = None) -> float:
        """One sample's current value (0 when absent); for tests and logs."""
        v = self.registry.get_sample_value(name, labels or {})
        return 0.0 if v is None else float(v)


class SupervisorMetrics:
    """The supervisor's own metrics (``posecast serve --workers N``), in the node's
    scrape under ``worker="supervisor"``."""

    def __init__(self) -> None:
        r = self.registry = CollectorRegistry(auto_describe=True)
        self.workers = Gauge(
            "posecast_workers", "Serving worker processes running (ready or starting)",
            registry=r,
        )  # fmt: skip
        self.worker_restarts = Counter(
            "posecast_worker_restarts",
            "Worker processes restarted after they exited unasked (crashed, killed)",
            registry=r,
        )
        self.relay_forwarded = Counter(
            "posecast_relay_forwarded", "Frames the node's relay wrote to a worker", registry=r
        )
        self.relay_dropped = Counter(
            "posecast_relay_dropped",
            "Pose batches the relay did not forward: the receiving worker was far behind",
            registry=r,
        )
        self._relay_seen = (0, 0)

    def relay_counts(self, forwarded: int, dropped: int) -> None:
        """Bring the relay's counters up to its running totals."""
        f0, d0 = self._relay_seen
        self.relay_forwarded.inc(forwarded - f0)
        self.relay_dropped.inc(dropped - d0)
        self._relay_seen = (forwarded, dropped)

    def render(self) -> bytes:
        out: bytes = generate_latest(self.registry)
        return out


class _Families:
    """A collector that yields families already built (for :func:`merge_expositions`)."""

    def __init__(self, families: Sequence[Metric]) -> None:
        self.families = families

    def collect(self) -> Iterator[Metric]:
        yield from self.families


def merge_expositions(parts: Sequence[tuple[str, bytes]]) -> bytes:
    """One exposition of several processes' (``(worker label, text)``): each family
    once, every sample with a ``worker`` label added. A part that does not parse is
    left out (and logged): one broken worker does not break the node's scrape."""
    merged: dict[str, Metric] = {}
    for label, text in parts:
        try:
            families = list(text_string_to_metric_families(text.decode()))
        except (ValueError, UnicodeDecodeError) as exc:
            log.warning("metrics of a worker left out", extra={"worker": label, "why": str(exc)})
            continue
        for fam in families:
            into = merged.get(fam.name)
            if into is None:
                into = merged[fam.name] = Metric(fam.name, fam.documentation, fam.type, fam.unit)
            for s in fam.samples:
                labels = {**s.labels, "worker": label}
                into.add_sample(s.name, labels, s.value, s.timestamp, s.exemplar)
    registry = CollectorRegistry(auto_describe=False)
    registry.register(_Families(list(merged.values())))
    out: bytes = generate_latest(registry)
    return out
