"""deploy/nginx/nginx.conf, run for real: nginx in front of two ``posecast serve
--redis`` nodes on loopback, players through it, one on each node, seeing each other.

The compose file's service names are replaced by loopback ports; everything else is
the shipped configuration. nginx comes from Debian's package: installed if missing
and we are root (as CI is), otherwise the test skips and says so.
"""

from __future__ import annotations

import asyncio
import os
import shutil
import subprocess
import time
import urllib.error
import urllib.request
from collections.abc import Iterator
from pathlib import Path

import pytest

from posecast.online.protocol.messages import Pose, Welcome
from tests.online.conftest import token
from tests.online.wsclient import Client
from tests.system.deploy.conftest import ROOT
from tests.system.scaleout.conftest import Node, RedisServer, free_port


@pytest.fixture(scope="session")
def nginx_bin() -> str:
    found = shutil.which("nginx") or shutil.which("nginx", path="/usr/sbin")
    if found:
        return found
    if os.geteuid() != 0:
        pytest.skip("nginx is not installed and this is not root: apt-get install -y nginx")
    env = {**os.environ, "DEBIAN_FRONTEND": "noninteractive"}
    for cmd in (["apt-get", "update", "-qq"], ["apt-get", "install", "-y", "-qq", "nginx"]):
        done = subprocess.run(cmd, env=env, capture_output=True, text=True, timeout=600)
        assert done.returncode == 0, done.stdout[-2000:] + done.stderr[-2000:]
    found = shutil.which("nginx") or shutil.which("nginx", path="/usr/sbin")
    assert found, "apt-get installed nginx but it is not on PATH"
    return found


@pytest.fixture
def balancer(
    nginx_bin: str, redis_server: RedisServer, tmp_path: Path
) -> Iterator[tuple[int, Node, Node]]:
    nodes = (Node("node-a", redis_server.url), Node("node-b", redis_server.url))
    nginx: subprocess.Popen[bytes] | None = None
    try:
        for n in nodes:
            n.wait_listening()
        for n in nodes:
            n.wait_ready()
        port = free_port()
        conf = (ROOT / "deploy/nginx/nginx.conf").read_text("utf-8")
        conf = conf.replace("node-a:8765", f"127.0.0.1:{nodes[0].port}")
        conf = conf.replace("node-b:8765", f"127.0.0.1:{nodes[1].port}")
        conf = conf.replace("listen 8765;", f"listen 127.0.0.1:{port};")
        conf = conf.replace("http {", f"http {{\n    access_log {tmp_path}/access.log;", 1)
        conf = f"pid {tmp_path}/nginx.pid;\nerror_log {tmp_path}/error.log;\n" + conf
        path = tmp_path / "nginx.conf"
        path.write_text(conf, "utf-8")
        check = subprocess.run([nginx_bin, "-t", "-c", str(path)], capture_output=True, text=True)
        assert check.returncode == 0, check.stderr
        nginx = subprocess.Popen([nginx_bin, "-c", str(path), "-g", "daemon off;"])
        deadline = time.monotonic() + 10
        while _get(port, "/lb-healthz") != 200:
            assert time.monotonic() < deadline, "nginx did not start"
            time.sleep(0.05)
        yield port, *nodes
    finally:
        if nginx is not None:
            nginx.terminate()
            nginx.wait(timeout=10)
        for n in nodes:
            n.close()


def _get(port: int, path: str) -> int:
    try:
        with urllib.request.urlopen(f"http://127.0.0.1:{port}{path}", timeout=2) as r:
            return int(r.status)
    except urllib.error.HTTPError as e:
        return e.code
    except OSError:
        return 0


@pytest.mark.timeout(300)  # may include installing redis-server / nginx with apt-get
def test_nginx_spreads_websockets_over_both_nodes_and_rooms_span_them(
    balancer: tuple[int, Node, Node],
) -> None:
    port, a, b = balancer
    assert _get(port, "/metrics") == 404, "per-node metrics are not exposed through the LB"

    async def scenario() -> None:
        p1, p2 = await Client.open(port), await Client.open(port)  # least_conn: one each
        assert isinstance(await p1.hello(token("r1", "p1"), name="P1"), Welcome)
        assert isinstance(await p2.hello(token("r1", "p2"), name="P2"), Welcome)
        p1.stream()
        p2.stream(seed=1)
        await p1.wait_for(lambda m: isinstance(m, Pose) and m.player == "p2", 10)
        await p2.wait_for(lambda m: isinstance(m, Pose) and m.player == "p1", 10)
        players = [n.http("/metrics")[1] for n in (a, b)]
        assert all("posecast_players 1.0" in m for m in players), "one player per node"
        for cl in (p1, p2):
            await cl.close()

    asyncio.run(scenario())
