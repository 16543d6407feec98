"""Graceful shutdown of a real ``posecast serve`` process on SIGTERM."""

from __future__ import annotations

import asyncio
import os
import re
import signal
import subprocess
import sys
import time

import pytest

from posecast.online.auth.tokens import mint
from posecast.online.protocol.messages import Bye, Welcome
from tests.online.wsclient import Client

DRAIN_S = 2.0


@pytest.mark.timeout(40)
def test_sigterm_says_bye_drains_and_exits_0() -> None:
    """Started with ``--dev``: it invents a secret and prints it; tokens use that."""
    env = {k: v for k, v in os.environ.items() if not k.startswith("POSECAST_")}
    proc = subprocess.Popen(
        [sys.executable, "-m", "posecast", "serve", "--dev", "--port", "0", "--samples", "8",
         "--drain-timeout-s", str(DRAIN_S)],
        env=env,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )  # fmt: skip
    try:
        assert proc.stdout is not None
        secret = re.search(r"token secret for this run: (\S+)", proc.stdout.readline())
        assert secret, "--dev did not print its secret"
        line = proc.stdout.readline()
        match = re.search(r"listening on ws://[\d.]+:(\d+)", line)
        assert match, line + (proc.stderr.read() if proc.stderr else "")
        port = int(match.group(1))

        async def scenario() -> float:
            clients = [await Client.open(port) for _ in range(3)]
            for i, cl in enumerate(clients):
                tok = mint(secret[1].encode(), room="r1", player=f"p{i}", now=time.time())
                assert isinstance(await cl.hello(tok), Welcome)
            clients[0].stream()
            await clients[1].wait_for(lambda m: m.TYPE == "pose")
            t0 = time.monotonic()
            proc.send_signal(signal.SIGTERM)
            for cl in clients:
                bye = await cl.wait_for(lambda m: isinstance(m, Bye), timeout=DRAIN_S)
                assert isinstance(bye, Bye) and bye.reason
                await asyncio.wait_for(cl.closed.wait(), DRAIN_S)
                assert cl.ws.close_code == 1001  # going away
            return t0

        t0 = asyncio.run(scenario())
        assert proc.wait(timeout=DRAIN_S + 5) == 0
        assert time.monotonic() - t0 < DRAIN_S + 3
        _, err = proc.communicate(timeout=5)
        assert '"event":"stopped"' in err, err[-2000:]
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.communicate()


@pytest.mark.timeout(20)
def test_serve_refuses_to_start_without_a_secret() -> None:
    env = {k: v for k, v in os.environ.items() if not k.startswith("POSECAST_")}
    out = subprocess.run(
        [sys.executable, "-m", "posecast", "serve", "--port", "0"],
        env=env,
        capture_output=True,
        text=True,
        timeout=15,
    )
    assert out.returncode == 2 and "POSECAST_TOKEN_SECRET" in out.stderr
