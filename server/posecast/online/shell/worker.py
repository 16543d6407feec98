"""One serving process of ``posecast serve --workers N``: ``python -m
posecast.online.shell.worker INDEX``, started by the supervisor
(:mod:`posecast.online.shell.workers`), never by hand.

It reads one JSON line on stdin (the supervisor's
:func:`~posecast.online.shell.workers.worker_spec`: the config, field by field, the
relay's path and, with ``--workers auto``, the CPU it keeps to), runs one
:class:`~posecast.online.shell.app.PosecastServer` as worker ``INDEX`` until SIGTERM
or SIGINT (the drain is one process's), writes ``ready`` on stdout once it serves,
and stops as well when its link to the relay ends (the supervisor is gone).
"""

from __future__ import annotations

import asyncio
import json
import logging
import os
import signal
import sys

from posecast.errors import PosecastError
from posecast.online.config import ServerConfig
from posecast.online.shell.app import PosecastServer, WorkerRole
from posecast.online.shell.logging import configure

log = logging.getLogger("posecast.server")


async def serve_worker(cfg: ServerConfig, role: WorkerRole) -> None:
    loop = asyncio.get_running_loop()
    stop = asyncio.Event()
    for sig in (signal.SIGTERM, signal.SIGINT):
        loop.add_signal_handler(sig, stop.set)
    server = PosecastServer(cfg, role=role)
    server.relay_lost = stop.set
    loop.add_signal_handler(signal.SIGHUP, server.reload_keys)
    await server.start()
    print("ready", flush=True)
    # Nothing more goes to stdout (a pipe the supervisor stops reading): logs go to stderr.
    devnull = os.open(os.devnull, os.O_WRONLY)
    os.dup2(devnull, sys.stdout.fileno())
    os.close(devnull)
    try:
        await stop.wait()
        if not server.link or server.link.connected:
            log.info("signal received: shutting down", extra={"worker": role.index})
        else:
            log.warning("relay gone: shutting down", extra={"worker": role.index})
    finally:
        await server.stop()


def main(argv: list[str] | None = None) -> int:
    args = sys.argv[1:] if argv is None else argv
    index = int(args[0])
    spec = json.loads(sys.stdin.readline())
    if spec.get("cpu") is not None:  # before any thread starts: they all inherit it
        os.sched_setaffinity(0, {int(spec["cpu"])})
    try:
        cfg = ServerConfig(**spec["config"])
        configure(cfg.log_level)
        asyncio.run(serve_worker(cfg, WorkerRole(index, str(spec["relay"]))))
    except PosecastError as exc:
        print(f"posecast: worker {index}: error [{exc.code}] {exc.message}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
