"""A real ``redis-server`` and real ``posecast serve --redis`` processes on loopback.

Nothing is faked: ``redis-server`` comes from Debian's package. If it is missing and
we are root (CI is), the session fixture installs it with ``apt-get`` and says how
long that took; otherwise the tests skip with a reason that says what to install.
Each test gets its own Redis (a free port, a temporary directory, no persistence)
and its own nodes. The helpers at the end drive players on them.
"""

from __future__ import annotations

import asyncio
import os
import shutil
import socket
import subprocess
import sys
import time
from collections.abc import Callable, Coroutine, Iterator
from pathlib import Path
from typing import Any

import pytest

from posecast.online.protocol.messages import Pose, Welcome
from posecast.testing.serve import ServeProcess
from posecast.testing.serve import http_get as http_get  # re-exported
from tests.online.conftest import SECRET, token
from tests.online.wsclient import Client
from tests.system.scaleout.redis_proxy import RedisProxy

HEARTBEAT_S = 1.0  # the defaults: the bound the tests check is the documented one
NODE_TTL_S = 3.0


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port: int = s.getsockname()[1]
        return port


@pytest.fixture(scope="session")
def redis_server_bin() -> str:
    found = shutil.which("redis-server")
    if found:
        return found
    if os.geteuid() != 0:
        pytest.skip(
            "MULTI-NODE TESTS NOT RUN: redis-server is not installed and this is not root; "
            "run `sudo apt-get install -y redis-server` (Debian) to run them"
        )
    env = {**os.environ, "DEBIAN_FRONTEND": "noninteractive"}
    t0 = time.monotonic()
    for cmd in (["apt-get", "update", "-qq"], ["apt-get", "install", "-y", "-qq", "redis-server"]):
        done = subprocess.run(cmd, env=env, capture_output=True, text=True, timeout=600)
        if done.returncode != 0:
            pytest.fail(f"{' '.join(cmd)} failed:\n{done.stdout[-2000:]}{done.stderr[-2000:]}")
    found = shutil.which("redis-server")
    assert found, "apt-get installed redis-server but it is not on PATH"
    sys.stderr.write(
        f"\n[scaleout] apt-get installed redis-server in {time.monotonic() - t0:.1f} s\n"
    )
    return found


class RedisServer:
    """One ``redis-server`` on a fixed loopback port that can be stopped and restarted."""

    def __init__(self, binary: str, workdir: Path) -> None:
        self.binary, self.dir, self.port = binary, workdir, free_port()
        self.proc: subprocess.Popen[bytes] | None = None

    @property
    def url(self) -> str:
        return f"redis://127.0.0.1:{self.port}/0"

    def start(self) -> None:
        cmd = [self.binary, "--port", str(self.port), "--bind", "127.0.0.1",
               "--dir", str(self.dir), "--save", "", "--appendonly", "no",
               "--daemonize", "no", "--loglevel", "warning"]  # fmt: skip
        self.proc = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        deadline = time.monotonic() + 10
        while time.monotonic() < deadline:
            try:
                with socket.create_connection(("127.0.0.1", self.port), timeout=0.5) as s:
                    s.sendall(b"PING\r\n")
                    if s.recv(16).startswith(b"+PONG"):
                        return
            except OSError:
                time.sleep(0.05)
        raise AssertionError(f"redis-server did not start on port {self.port}")

    def stop(self) -> None:
        if self.proc is not None and self.proc.poll() is None:
            self.proc.terminate()
            self.proc.wait(timeout=10)
        self.proc = None


@pytest.fixture
def redis_server(redis_server_bin: str, tmp_path: Path) -> Iterator[RedisServer]:
    server = RedisServer(redis_server_bin, tmp_path)
    server.start()
    try:
        yield server
    finally:
        server.stop()


@pytest.fixture
def redis_proxy(redis_server: RedisServer) -> Iterator[RedisProxy]:
    """A :class:`~tests.system.scaleout.redis_proxy.RedisProxy` in front of ``redis_server``."""
    proxy = RedisProxy(redis_server.port)
    try:
        yield proxy
    finally:
        proxy.close()


class Node(ServeProcess):
    """One ``posecast serve --redis URL`` subprocess (8 samples, look-ahead 2): a
    :class:`~posecast.testing.serve.ServeProcess`, listening once constructed."""

    def __init__(self, name: str, redis_url: str, *extra: str) -> None:
        self.name = name
        super().__init__(
            "--redis", redis_url, "--node-id", name,
            "--redis-heartbeat-s", str(HEARTBEAT_S), "--redis-node-ttl-s", str(NODE_TTL_S),
            "--conn-per-ip-per-min", "10000", "--fatal-per-ip-per-min", "10000",
            "--sockets-per-ip", "10000", *extra,
            secret=SECRET, samples=8, lookahead=2,
        )  # fmt: skip

    def wait_listening(self) -> None:
        """Nothing left to wait for: the constructor has read the port."""

    def wait_ready(self, timeout_s: float = 10.0) -> None:
        super().wait_ready(timeout_s)

    def close(self) -> None:
        self.stop(timeout_s=15)


@pytest.fixture
def nodes(redis_server: RedisServer) -> Iterator[tuple[Node, Node]]:
    """Nodes A and B on one Redis, started one after the other, both ready."""
    pair: list[Node] = []
    try:
        for name in ("node-a", "node-b"):
            pair.append(Node(name, redis_server.url))
        for n in pair:
            n.wait_ready()
        yield pair[0], pair[1]
    finally:
        for n in pair:
            n.close()


def run(coro: Coroutine[Any, Any, None]) -> None:
    asyncio.run(coro)


async def player(node: Node, name: str, room: str = "r1", seed: int = 0) -> Client:
    """A player joined on ``node``, streaming a synthetic walk."""
    cl = await Client.open(node.port)
    assert isinstance(await cl.hello(token(room, name), room=room, name=name.upper()), Welcome)
    cl.stream(seed=seed)
    return cl


def pose_from(src: str) -> Callable[[Any], bool]:
    return lambda m: isinstance(m, Pose) and m.player == src


async def until(what: str, check: Callable[[], bool], timeout_s: float = 15.0) -> None:
    """Wait for ``check()``, failing with ``what`` after ``timeout_s``."""
    deadline = time.monotonic() + timeout_s
    while not check():
        assert time.monotonic() < deadline, f"not in {timeout_s} s: {what}"
        await asyncio.sleep(0.05)
