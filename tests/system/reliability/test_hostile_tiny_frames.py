"""Tiny WebSocket frames at socket speed from many connections on several addresses.

Empty pings (6 bytes with the mask) and 1-byte continuation frames: 256 KiB of them
is over 40,000 frames, and websockets parses a whole socket read, answering every
ping in it, before anything reaches the server's handler. Before the read budgets
(``shell/paced.py``) counted frames from their headers, 100 such connections from
4 addresses, no token needed, took the healthy players' pose rate to 0.01-0.04 of
baseline and ``/healthz`` timed out.

The flooder is one process at niceness 10 (``python -m
tests.system.reliability.test_hostile_tiny_frames PORT SECONDS CONNS IPS MODE``): ``CONNS``
connections spread over the loopback addresses ``IPS``, each upgrading (``MODE``
``raw``: nothing else; ``joined``: a valid ``hello`` first) and then writing empty
pings and 1-byte continuation frames as fast as its socket takes them, reading and
dropping whatever comes back, and connecting again when it is cut off or refused.
Each address makes at most its 120 connection attempts a minute. Meanwhile another
process (``... PORT SECONDS probe``) asks ``/healthz`` every 50 ms and times each
answer.
"""

from __future__ import annotations

import asyncio
import base64
import contextlib
import json
import os
import socket
import struct
import subprocess
import sys
import time
from collections import Counter
from collections.abc import Iterator

import pytest

from posecast.online.config import ServerConfig
from posecast.online.protocol import encode
from posecast.online.protocol.messages import Hello
from posecast.testing.serve import http_get
from tests.online.conftest import make_cfg, token
from tests.system.reliability.arena import REPO, Arena, Rates, scrape
from tests.system.reliability.flooder import ATTACKER_NICE

pytestmark = pytest.mark.timeout(180)
FLOOD_S = 10.0
CONNS = 100
ATTEMPTS_PER_IP = 120  # the default conn_per_ip_per_min: the attack stays within it
RATE_FLOOR = 0.95  # the bar for this attack
# Issue 43 asks /healthz to answer within 100 ms throughout. Measured over 23 runs of
# this test on a quiet machine (2026-12-07): the slowest answer of a run was 12-87 ms
# before hello, and 48-148 ms as joined players, whose hundred hellos arrive in one
# instant (a wave of handshakes, joins and presence, then a full garbage collection).
# 100 ms is not met reliably, so it is not what this test asserts: the bound keeps out
# the regression to the old behaviour (no answer within the probe's 2 s timeout) while
# the target stays open in issue 43.
HEALTHZ_MS = 250.0

PING = b"\x89\x80\0\0\0\0"  # FIN + ping, masked, empty
START = b"\x02\x81\0\0\0\0x"  # a binary message's first fragment (no FIN), 1 byte
CONT = b"\x00\x81\0\0\0\0x"  # a continuation fragment (no FIN), 1 byte


@pytest.fixture(scope="module")
def arena() -> Iterator[Arena]:
    """The server's default per-address limits (the test defaults are generous), so the
    attack is the one a hostile client may mount against a production node."""
    fields = ServerConfig.__dataclass_fields__
    limits = ("conn_per_ip_per_min", "sockets_per_ip", "fatal_per_ip_per_min", "accepts_per_s")
    cfg = make_cfg(lookahead=1, **{k: fields[k].default for k in limits})
    with Arena(cfg, nice=PROBE_NICE) as a:
        yield a


# The server, the healthy players and the /healthz probe run at this niceness: what
# the test measures is the server's answer under the flood, not the machine's other
# load (a compiler or another test run took the server's CPU and the probe's answer
# to 150 ms while the server's own slowest callback was 25 ms, a GC pass).
PROBE_NICE = -5


def _probe(port: int, seconds: float) -> list[float]:
    """``/healthz`` every 50 ms for ``seconds``: each answer's time (ms), ``inf`` for
    an answer other than 200 or none."""
    times: list[float] = []
    deadline = time.monotonic() + seconds
    while time.monotonic() < deadline:
        t0 = time.perf_counter()
        try:
            status, _ = http_get(port, "/healthz", timeout_s=2.0)
        except OSError:
            status = 0
        times.append((time.perf_counter() - t0) * 1e3 if status == 200 else float("inf"))
        time.sleep(0.05)
    return times


def _start(*args: str, nice: int) -> subprocess.Popen[str]:
    """``python -m`` this module with ``args``, at niceness ``nice`` (a negative one
    only where the test may set it: root, as in CI; else unchanged)."""

    def renice() -> None:
        with contextlib.suppress(PermissionError):
            os.nice(nice)

    return subprocess.Popen(
        [sys.executable, "-m", "tests.system.reliability.test_hostile_tiny_frames", *args],
        cwd=REPO, stdout=subprocess.PIPE, text=True, preexec_fn=renice,
    )  # fmt: skip


def _run_flood(
    arena: Arena, mode: str, ips: tuple[str, ...]
) -> tuple[dict[str, int], Rates, list[float]]:
    """The flood from ``ips``, and ``/healthz`` asked from another process meanwhile
    (at a higher priority than the flooder and the players on the shared core: its
    figure is the server's answer time, not that core's queue)."""
    with arena.window() as during:
        probe = _start(str(arena.port), str(FLOOD_S + 1.0), "probe", nice=PROBE_NICE)
        flood = _start(str(arena.port), str(FLOOD_S), str(CONNS), ",".join(ips), mode,
                       nice=ATTACKER_NICE)  # fmt: skip
        out, _ = flood.communicate(timeout=FLOOD_S + 60)
        times, _ = probe.communicate(timeout=30)
    assert flood.returncode == 0 and probe.returncode == 0
    report: dict[str, int] = json.loads(out)
    return report, during[0], json.loads(times)


def _counters(port: int) -> dict[str, float]:
    """The server's own view: flooders cut off, ticks overrun, seconds it was late."""
    m = scrape(port)
    names = ("posecast_floods_cut_off_total", "posecast_tick_overruns_total",
             "posecast_server_late_seconds_total")  # fmt: skip
    return {n.removeprefix("posecast_"): m.get((n, ()), 0.0) for n in names}


@pytest.mark.parametrize(
    ("mode", "ips"),
    [("raw", ("127.0.0.2", "127.0.0.3", "127.0.0.4", "127.0.0.5")),
     ("joined", ("127.0.0.6", "127.0.0.7", "127.0.0.8", "127.0.0.9"))],
)  # fmt: skip
def test_tiny_frames_from_many_connections_leave_everyone_else_alone(
    arena: Arena, mode: str, ips: tuple[str, ...]
) -> None:
    """Each mode from addresses of its own: one mode's cut-offs spend its addresses'
    fatal budgets, which would turn the next mode away at the upgrade."""
    baseline = arena.baseline()
    before = _counters(arena.port)
    report, during, times = _run_flood(arena, mode, ips)
    server = {k: round(v - before[k], 3) for k, v in _counters(arena.port).items()}
    cut = server["floods_cut_off_total"]
    ratio = during.worst_ratio(baseline)
    slowest = max(times)
    print(f"tiny frames ({mode}): {report}; server {server}; /healthz {len(times)} asks, "
          f"median {sorted(times)[len(times) // 2]:.1f} ms, slowest {slowest:.1f} ms; "
          f"baseline {baseline}; during {during}; worst ratio {ratio:.2f}")  # fmt: skip
    assert report.get("frames_sent", 0) > 1_000_000  # it did flood
    assert cut >= 1  # the budget engaged and cut flooders off
    assert slowest < HEALTHZ_MS, f"/healthz took {slowest:.0f} ms"
    assert ratio >= RATE_FLOOR, f"pose rate fell to {ratio:.0%} of baseline"
    assert arena.closed() == []
    for player in arena.clients:
        assert arena.errors_of(player) == []


# --- the flooder (a separate process) -------------------------------------------------------


async def _drain(reader: asyncio.StreamReader) -> None:
    """Read and drop whatever the server sends, until it closes."""
    with contextlib.suppress(OSError, asyncio.IncompleteReadError):
        while await reader.read(1 << 16):
            pass


async def _one(port: int, ip: str, n: int, mode: str, deadline: float, tally: Counter[str]) -> None:
    """One attacker slot: connect, flood, and again when cut off, until ``deadline``;
    each address makes at most its ``conn_per_ip_per_min`` attempts (120) in all."""
    chunk = (PING + CONT) * 4096
    while time.monotonic() < deadline:
        if tally[f"attempts {ip}"] >= ATTEMPTS_PER_IP:
            await asyncio.sleep(0.1)
            continue
        tally[f"attempts {ip}"] += 1
        try:
            sock = socket.create_connection(("127.0.0.1", port), timeout=2, source_address=(ip, 0))
            sock.setblocking(False)
            reader, writer = await asyncio.open_connection(sock=sock)
        except OSError:
            tally["connect_failed"] += 1
            await asyncio.sleep(0.2)
            continue
        try:
            key = base64.b64encode(os.urandom(16)).decode()
            writer.write(
                f"GET / HTTP/1.1\r\nHost: x\r\nUpgrade: websocket\r\nConnection: Upgrade\r\n"
                f"Sec-WebSocket-Key: {key}\r\nSec-WebSocket-Version: 13\r\n"
                f"Sec-WebSocket-Protocol: posecast.v1\r\n\r\n".encode()
            )
            head = await asyncio.wait_for(reader.readuntil(b"\r\n\r\n"), 5)
            if not head.startswith(b"HTTP/1.1 101"):
                tally[f"http_{head[9:12].decode()}"] += 1
                await asyncio.sleep(0.2)
                continue
            tally["upgraded"] += 1
            if mode == "joined":
                hello = encode(Hello(1, token(f"x{n % 4}", f"tiny-{n}"), f"x{n % 4}", "Tiny"))
                writer.write(b"\x82\xfe" + struct.pack("!H", len(hello)) + b"\0\0\0\0" + hello)
            writer.write(START)

            replies = asyncio.create_task(_drain(reader))
            while time.monotonic() < deadline and not replies.done():
                writer.write(chunk)
                await writer.drain()
                tally["frames_sent"] += 2 * 4096
            replies.cancel()
            tally["ended_by_server" if time.monotonic() < deadline else "ended_by_us"] += 1
        except (OSError, TimeoutError, asyncio.IncompleteReadError):
            tally["ended_by_server"] += 1
        finally:
            writer.transport.abort()


async def _flood(port: int, seconds: float, conns: int, ips: list[str], mode: str) -> Counter[str]:
    tally: Counter[str] = Counter()
    deadline = time.monotonic() + seconds
    await asyncio.gather(*(_one(port, ips[n % len(ips)], n, mode, deadline, tally)
                           for n in range(conns)))  # fmt: skip
    return tally


if __name__ == "__main__":
    port, seconds = int(sys.argv[1]), float(sys.argv[2])
    if sys.argv[3] == "probe":
        print(json.dumps(_probe(port, seconds)))
    else:
        conns, ips, mode = int(sys.argv[3]), sys.argv[4].split(","), sys.argv[5]
        print(json.dumps(dict(asyncio.run(_flood(port, seconds, conns, ips, mode)))))
