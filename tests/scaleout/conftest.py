"""A real ``redis-server`` and real ``posecast serve --redis`` processes on loopback.

Nothing is faked: ``redis-server`` comes from Debian's package. If it is missing and
we are root (CI is), the session fixture installs it with ``apt-get`` and says how
long that took; otherwise the tests skip with a reason that says what to install.
Each test gets its own Redis (a free port, a temporary directory, no persistence)
and its own nodes.
"""

from __future__ import annotations

import os
import re
import shutil
import signal
import socket
import subprocess
import sys
import time
import urllib.error
import urllib.request
from collections.abc import Iterator
from pathlib import Path

import pytest

from tests.online.conftest import SECRET

HEARTBEAT_S = 1.0  # the defaults: the bound the tests check is the documented one
NODE_TTL_S = 3.0


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port: int = s.getsockname()[1]
        return port


def http_get(port: int, path: str) -> tuple[int, str]:
    """``GET path`` on a loopback server: status and body, error statuses included."""
    try:
        with urllib.request.urlopen(f"http://127.0.0.1:{port}{path}", timeout=2) as r:
            return r.status, r.read().decode()
    except urllib.error.HTTPError as e:
        return e.code, e.read().decode()


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


class Node:
    """One ``posecast serve --redis URL`` subprocess."""

    def __init__(self, name: str, redis_url: str, *extra: str) -> None:
        env = {k: v for k, v in os.environ.items() if not k.startswith("POSECAST_")}
        env.update(POSECAST_TOKEN_SECRET=SECRET, POSECAST_LOG_LEVEL="WARNING")
        cmd = [sys.executable, "-m", "posecast", "serve", "--port", "0", "--samples", "8",
               "--lookahead", "2", "--redis", redis_url, "--node-id", name,
               "--redis-heartbeat-s", str(HEARTBEAT_S), "--redis-node-ttl-s", str(NODE_TTL_S),
               "--conn-per-ip-per-min", "10000", *extra]  # fmt: skip
        self.name = name
        self.proc = subprocess.Popen(cmd, env=env, stdout=subprocess.PIPE, text=True)
        self.port = 0

    def wait_listening(self) -> None:
        assert self.proc.stdout is not None
        line = self.proc.stdout.readline()
        match = re.search(r"listening on ws://[\d.]+:(\d+)", line)
        assert match, f"node {self.name} did not start: {line!r}"
        self.port = int(match.group(1))

    def http(self, path: str) -> tuple[int, str]:
        return http_get(self.port, path)

    def wait_ready(self, timeout: float = 10.0) -> None:
        deadline = time.monotonic() + timeout
        while self.http("/readyz")[0] != 200:
            assert time.monotonic() < deadline, f"node {self.name}: {self.http('/readyz')}"
            time.sleep(0.05)

    def kill(self) -> None:
        if self.proc.poll() is None:
            self.proc.send_signal(signal.SIGKILL)
            self.proc.wait(timeout=10)

    def close(self) -> None:
        if self.proc.poll() is None:
            self.proc.terminate()
            try:
                self.proc.wait(timeout=15)
            except subprocess.TimeoutExpired:
                self.kill()
        if self.proc.stdout is not None:
            self.proc.stdout.close()


@pytest.fixture
def nodes(redis_server: RedisServer) -> Iterator[tuple[Node, Node]]:
    """Nodes A and B on one Redis, started together, both ready."""
    pair = (Node("node-a", redis_server.url), Node("node-b", redis_server.url))
    try:
        for n in pair:
            n.wait_listening()
        for n in pair:
            n.wait_ready()
        yield pair
    finally:
        for n in pair:
            n.close()
