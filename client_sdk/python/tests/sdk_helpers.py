"""Test helpers: a real ``posecast serve --dev`` subprocess, and an event recorder.

The server comes from the repo's virtualenv (or ``$POSECAST_BIN``); tests that need
one are skipped where it is not installed (an SDK-only checkout).
"""

from __future__ import annotations

import asyncio
import contextlib
import os
import queue
import re
import shutil
import signal
import subprocess
import sys
import threading
from collections.abc import AsyncIterable, AsyncIterator, Callable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any, TypeVar

import pytest

import posecast_client as pc
from posecast_client import mint_token

T = TypeVar("T")

REPO = Path(__file__).resolve().parents[3]
DATA = Path(__file__).resolve().parent / "data"


def posecast_bin() -> str | None:
    candidates = [
        os.environ.get("POSECAST_BIN", ""),
        str(Path(sys.executable).with_name("posecast")),
        str(REPO / ".venv" / "bin" / "posecast"),
        shutil.which("posecast") or "",
    ]
    return next((c for c in candidates if c and os.access(c, os.X_OK)), None)


@dataclass
class DevServer:
    proc: subprocess.Popen[str]
    pump: threading.Thread  # drains the server's stdout
    url: str
    port: int
    secret: str

    def token(self, room: str, player: str, role: str = "player", **kw: Any) -> str:
        return mint_token(self.secret, room=room, player=player, role=role, **kw)

    def stop(self, sig: int = signal.SIGTERM, timeout_s: float = 10.0) -> None:
        if self.proc.poll() is None:
            self.proc.send_signal(sig)
            try:
                self.proc.wait(timeout_s)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait()
        self.pump.join(5.0)
        if self.proc.stdout is not None:
            self.proc.stdout.close()


def start_server(
    log: Path, *, port: int = 0, secret: str | None = None, layouts: str | None = None
) -> DevServer:
    """Start ``posecast serve --dev --port PORT --samples 8`` (``--layouts LAYOUTS``
    when given) and wait until it listens."""
    exe = posecast_bin()
    if exe is None:
        pytest.skip("the posecast server is not installed here")
    env = dict(
        os.environ,
        POSECAST_CONN_PER_IP_PER_MIN="100000",
        POSECAST_SOCKETS_PER_IP="100000",
        POSECAST_LOG_LEVEL="WARNING",
    )
    env.pop("POSECAST_TOKEN_SECRET", None)
    if secret is not None:
        env["POSECAST_TOKEN_SECRET"] = secret
    cmd = [exe, "serve", "--dev", "--port", str(port), "--samples", "8"]
    if layouts is not None:
        cmd += ["--layouts", layouts]
    with log.open("a") as err:
        proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=err, text=True, env=env)
    lines: queue.Queue[str] = queue.Queue()

    def pump() -> None:
        assert proc.stdout is not None
        for line in proc.stdout:
            lines.put(line)
        lines.put("")

    thread = threading.Thread(target=pump, daemon=True)
    thread.start()
    url = None
    while url is None:
        try:
            line = lines.get(timeout=30.0)
        except queue.Empty:
            DevServer(proc, thread, "", 0, "").stop(signal.SIGKILL)
            raise RuntimeError("posecast serve did not start in 30 s") from None
        if not line:
            DevServer(proc, thread, "", 0, "").stop()
            raise RuntimeError(f"posecast serve exited: {log.read_text()[-2000:]}")
        if m := re.search(r"secret for this run: (\S+)", line):
            secret = m.group(1)
        if m := re.search(r"listening on (ws://\S+)", line):
            url = m.group(1) + "/"
    assert secret is not None
    return DevServer(proc, thread, url, int(url.rstrip("/").rsplit(":", 1)[1]), secret)


@contextlib.contextmanager
def dev_server_at(log: Path, **kw: Any) -> Iterator[DevServer]:
    server = start_server(log, **kw)
    try:
        yield server
    finally:
        server.stop()


class EventLog:
    """Reads a client's events in the background and keeps them all."""

    def __init__(self, client: pc.Client) -> None:
        self.events: list[pc.Event] = []
        self.failure: BaseException | None = None
        self._new = asyncio.Event()
        self._task = asyncio.create_task(self._read(client))

    async def _read(self, client: pc.Client) -> None:
        try:
            async for event in client.events():
                self.events.append(event)
                self._new.set()
        except Exception as exc:
            self.failure = exc
            self._new.set()

    async def wait_for(
        self, pred: Callable[[pc.Event], bool], start: int = 0, timeout_s: float = 15.0
    ) -> pc.Event:
        """The first event from index ``start`` on that matches ``pred``."""
        async with asyncio.timeout(timeout_s):
            i = start
            while True:
                while i < len(self.events):
                    if pred(self.events[i]):
                        return self.events[i]
                    i += 1
                if self.failure is not None:
                    raise self.failure
                self._new.clear()
                await self._new.wait()

    def stop(self) -> None:
        self._task.cancel()


async def for_seconds(source: AsyncIterable[T], seconds: float) -> AsyncIterator[T]:
    """``source``'s items for ``seconds`` of the running loop's time, then stop."""
    end = asyncio.get_running_loop().time() + seconds
    async for s in source:
        if asyncio.get_running_loop().time() >= end:
            return
        yield s
