"""``posecast serve --workers N`` (N > 1): a supervisor and N serving processes.

One Python process runs its event loop and its engine's glue under one interpreter
lock, so a node of one process leaves cores idle while the tick and the sockets take
turns on one (docs/engine.md, Capacity). Here the supervisor runs no engine and
touches no WebSocket frame. It:

1. binds the port once (``SO_REUSEPORT``, never listening itself): a port in use or
   an unknown host fails here, as without workers, and ``--port 0`` picks the one
   port every worker then shares;
2. runs the node's relay (:class:`~posecast.online.cluster.relay.Relay`) on a
   Unix-domain socket in a private temporary directory: the workers' ``local`` bus,
   and the node's merged ``/metrics``;
3. starts N workers (``python -m posecast.online.shell.worker I``), each handed the
   same :class:`~posecast.online.config.ServerConfig`, serialised on its stdin (never
   re-parsed from flags or the environment; secrets never on a command line), its
   node id (``NODE-wI``), and the relay's path; with ``--workers auto`` also a CPU of
   its own (:func:`worker_cpus`; its engine then runs one thread). Each runs today's
   :class:`~posecast.online.shell.app.PosecastServer` on the shared port, and the
   kernel spreads new connections over the listening workers;
4. reports the port once every worker is ready, and restarts a worker that exits
   unasked (``posecast_worker_restarts_total``): its players' connections are gone,
   and the SDKs reconnect to the workers still listening;
5. forwards SIGTERM and SIGINT (the workers drain, as one process does, then exit;
   so does the supervisor) and SIGHUP (re-read the token key set).
"""

from __future__ import annotations

import asyncio
import contextlib
import dataclasses
import errno
import json
import logging
import os
import shutil
import signal
import socket
import sys
import tempfile
import time
from collections.abc import Callable
from dataclasses import dataclass

from posecast.errors import WorkerError
from posecast.online.cluster.bus import default_node_id
from posecast.online.cluster.relay import Relay
from posecast.online.config import ServerConfig
from posecast.online.metrics import SupervisorMetrics, merge_expositions

log = logging.getLogger("posecast.server")
WORKER_MODULE = "posecast.online.shell.worker"
_MAX_NODE_CHARS = 52  # node ids are at most 64 characters, and get "-wI.G" added
_QUICK_EXIT_S = 5.0  # a worker that dies sooner after its start is restarted after a backoff


def reserve_port(host: str, port: int, tries: int = 5) -> tuple[list[socket.socket], int]:
    """Bind ``port`` on every address ``host`` names (``""``: every IPv4 and IPv6
    interface, as the single process binds), with ``SO_REUSEPORT`` and without
    listening: the port is this node's while the sockets are open, and only the
    workers' listening sockets take connections. ``port`` 0 picks one free port for
    all addresses. Raises ``OSError`` as a bind does (port in use, unknown host)."""
    infos = socket.getaddrinfo(host or None, port, type=socket.SOCK_STREAM, flags=socket.AI_PASSIVE)
    addrs = list(dict.fromkeys((fam, sa) for fam, _, _, _, sa in infos))
    for _ in range(tries):
        held: list[socket.socket] = []
        at = port
        try:
            for fam, sa in addrs:
                s = socket.socket(fam, socket.SOCK_STREAM)
                held.append(s)
                s.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
                s.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEPORT, 1)
                if fam == socket.AF_INET6:
                    s.setsockopt(socket.IPPROTO_IPV6, socket.IPV6_V6ONLY, 1)
                s.bind((sa[0], at, *sa[2:]))
                at = s.getsockname()[1]
            return held, at
        except OSError as exc:
            for s in held:
                s.close()
            if port != 0 or exc.errno != errno.EADDRINUSE:
                raise  # taken on another address in between: with port 0, another try
    raise OSError(errno.EADDRINUSE, f"no one free port on every address of {host!r}")


def worker_spec(cfg: ServerConfig, index: int, relay: str, cpu: int | None = None) -> bytes:
    """What worker ``index`` reads on its stdin: the config, field by field, the relay's
    path, and the CPU it keeps to (``None``: any the supervisor may use)."""
    config = {f.name: getattr(cfg, f.name) for f in dataclasses.fields(cfg)}
    spec = {"config": config, "index": index, "relay": relay, "cpu": cpu}
    return json.dumps(spec).encode() + b"\n"


def worker_cpus(cfg: ServerConfig) -> list[int]:
    """With ``--workers auto`` (a worker per CPU this process may use), worker ``i``
    keeps to the ``i``-th of those CPUs, its threads with it, so the workers' ticks do
    not take each other's cores; with a number of workers, none is pinned (``[]``)."""
    return sorted(os.sched_getaffinity(0)) if cfg.workers == "auto" else []


@dataclass
class _Slot:
    index: int
    proc: asyncio.subprocess.Process | None = None
    generation: int = 0
    started_at: float = 0.0
    quick_exits: int = 0


class Supervisor:
    """N worker processes on ``cfg.port`` (already reserved), the relay at ``relay``."""

    def __init__(self, cfg: ServerConfig, relay: Relay, metrics: SupervisorMetrics) -> None:
        self.cfg, self.relay, self.metrics = cfg, relay, metrics
        self.node = (cfg.node_id or default_node_id())[:_MAX_NODE_CHARS]
        self.slots = [_Slot(i) for i in range(cfg.worker_count)]
        self.cpus = worker_cpus(cfg)
        self.stopping = False
        self._watchers: list[asyncio.Task[None]] = []

    async def start(self) -> None:
        """Every worker started and ready, or ``WorkerError`` (the others stopped)."""
        try:
            async with asyncio.TaskGroup() as tg:
                for slot in self.slots:
                    tg.create_task(self._spawn(slot))
        except* WorkerError as group:
            await self.stop()
            raise group.exceptions[0] from None
        self._watchers = [asyncio.create_task(self._watch(s)) for s in self.slots]

    async def _spawn(self, slot: _Slot) -> None:
        """Start ``slot``'s worker and wait until it is ready (``WorkerError`` if it
        exits first)."""
        gen = f".{slot.generation}" if slot.generation else ""
        cfg = self.cfg.replace(node_id=f"{self.node}-w{slot.index}{gen}")
        cpu = self.cpus[slot.index] if slot.index < len(self.cpus) else None
        if cpu is not None:  # one CPU: a pool of more threads would only take turns on it
            cfg = cfg.replace(engine_threads=1)
        slot.generation += 1
        slot.started_at = time.monotonic()
        proc = slot.proc = await asyncio.create_subprocess_exec(
            sys.executable, "-m", WORKER_MODULE, str(slot.index),
            stdin=asyncio.subprocess.PIPE, stdout=asyncio.subprocess.PIPE,
        )  # fmt: skip
        assert proc.stdin is not None and proc.stdout is not None
        proc.stdin.write(worker_spec(cfg, slot.index, self.relay.path, cpu))
        with contextlib.suppress(ConnectionError):
            await proc.stdin.drain()
        proc.stdin.close()
        self.metrics.workers.set(sum(s.proc is not None for s in self.slots))
        line = await proc.stdout.readline()
        if line.strip() != b"ready":
            status = await proc.wait()
            raise WorkerError(
                f"worker {slot.index} exited with status {status} before it was ready"
                " (its log above says why)",
                worker=slot.index,
                status=status,
            )

    async def _watch(self, slot: _Slot) -> None:
        """Restart ``slot``'s worker whenever it exits unasked."""
        while True:
            assert slot.proc is not None
            status = await slot.proc.wait()
            if self.stopping:
                return
            lived = time.monotonic() - slot.started_at
            slot.quick_exits = slot.quick_exits + 1 if lived < _QUICK_EXIT_S else 0
            self.metrics.worker_restarts.inc()
            log.warning(
                "worker exited: restarting it",
                extra={"worker": slot.index, "status": status, "lived_s": round(lived, 1)},
            )
            if slot.quick_exits:  # crashing at start: do not spin
                await asyncio.sleep(min(5.0, 0.1 * 2**slot.quick_exits))
                if self._stopped():
                    return
            try:
                await self._spawn(slot)
            except WorkerError as exc:
                log.error("worker restart failed", extra={"worker": slot.index, "why": exc.message})

    def _stopped(self) -> bool:
        return self.stopping  # read after an await (a stop may have begun meanwhile)

    def forward(self, sig: signal.Signals) -> None:
        """Pass ``sig`` on to every worker alive."""
        for slot in self.slots:
            if slot.proc is not None and slot.proc.returncode is None:
                with contextlib.suppress(ProcessLookupError):
                    slot.proc.send_signal(sig)

    async def stop(self) -> None:
        """SIGTERM to every worker (each drains, as one process does); SIGKILL to one
        still there well past the drain."""
        self.stopping = True
        self.forward(signal.SIGTERM)
        limit = self.cfg.drain_timeout_s + self.cfg.close_timeout_s + 10.0
        procs = [s.proc for s in self.slots if s.proc is not None]
        waits = [asyncio.create_task(p.wait()) for p in procs]
        if waits:
            _, late = await asyncio.wait(waits, timeout=limit)
            for p in procs:
                if p.returncode is None:
                    log.error("worker did not stop: killed", extra={"pid": p.pid})
                    with contextlib.suppress(ProcessLookupError):
                        p.kill()
            if late:
                await asyncio.wait(late)
        for task in self._watchers:
            task.cancel()
            with contextlib.suppress(asyncio.CancelledError):
                await task
        self.metrics.workers.set(0)


async def supervise(cfg: ServerConfig, on_ready: Callable[[int], None]) -> None:
    """``posecast serve`` with ``cfg.worker_count`` > 1: until SIGTERM or SIGINT, then
    the workers drain and the supervisor exits after them."""
    loop = asyncio.get_running_loop()
    stop = asyncio.Event()
    held, port = reserve_port(cfg.host, cfg.port)
    tmp = tempfile.mkdtemp(prefix="posecast-node-")  # 0700: only this user reaches the relay
    metrics = SupervisorMetrics()

    def own_metrics() -> bytes:
        metrics.relay_counts(relay.counts.forwarded, relay.counts.dropped)
        return metrics.render()

    relay = Relay(
        os.path.join(tmp, "relay.sock"), own_metrics=own_metrics, merge=merge_expositions,
        replay_cache=cfg.replay_cache, token_leeway_s=cfg.token_leeway_s,
    )  # fmt: skip
    sup = Supervisor(cfg.replace(port=port), relay, metrics)
    try:
        await relay.start()
        for sig in (signal.SIGTERM, signal.SIGINT):
            loop.add_signal_handler(sig, stop.set)
        loop.add_signal_handler(signal.SIGHUP, sup.forward, signal.SIGHUP)
        await sup.start()
        log.info("workers ready", extra={"workers": len(sup.slots), "port": port})
        on_ready(port)
        await stop.wait()
        log.info("signal received: shutting down the workers")
    finally:
        await sup.stop()
        await relay.stop()
        for s in held:
            s.close()
        shutil.rmtree(tmp, ignore_errors=True)
