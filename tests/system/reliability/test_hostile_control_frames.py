"""WebSocket control frames as a flood: pings, before any ``hello``.

websockets answers every ping frame with a pong itself, before any message reaches
the server's handler, so the handler's read pacing (which counts messages) never saw
them: one connection from 127.0.0.2 that sent nothing but pings, no token needed,
took the event loop (the healthy players' tick fell to 16 Hz, 0.27 of baseline) and,
not reading its pongs, piled them up in the server's memory (+400 MB in 18 s). The
server now counts frames from their headers before websockets parses them
(``shell/paced.py``, read budgets): a few control frames a second are read, so at
most that many pongs are written, and the flood waits on the flooder's side.

The flooder is a raw socket in a process of its own (``python -m
tests.system.reliability.test_hostile_control_frames PORT SECONDS READ``).
"""

from __future__ import annotations

import base64
import contextlib
import json
import os
import socket
import subprocess
import sys
import threading
import time
from collections.abc import Iterator

import pytest

from tests.online.conftest import make_cfg
from tests.system.reliability.arena import REPO, Arena, assert_rates_kept, scrape
from tests.system.reliability.flooder import ATTACKER_NICE
from tests.system.reliability.hostile_helpers import OTHER_IP

pytestmark = pytest.mark.timeout(120)
FLOOD_S = 2.0
PING = b"\x89\xfd" + b"\0\0\0\0" + b"x" * 125  # FIN + ping, masked (zero key), 125 bytes
PONG_BYTES = 2 + 125  # the server's pong: unmasked
ONE_READ = 256 * 1024 // len(PING) + 1  # pings in one socket read (asyncio reads 256 KiB)


@pytest.fixture(scope="module")
def arena() -> Iterator[Arena]:
    with Arena(make_cfg(lookahead=1, hello_timeout_s=10.0)) as a:
        yield a


def _flood(port: int, seconds: float, read: bool) -> dict[str, int]:
    """Upgrade, then send nothing but ping frames for ``seconds``; count the bytes the
    server sent back (all pongs: no hello, so no message and no timeout in that time)."""
    s = socket.create_connection(("127.0.0.1", port), timeout=5, source_address=(OTHER_IP, 0))
    key = base64.b64encode(os.urandom(16)).decode()
    s.sendall(
        f"GET / HTTP/1.1\r\nHost: x\r\nUpgrade: websocket\r\nConnection: Upgrade\r\n"
        f"Sec-WebSocket-Key: {key}\r\nSec-WebSocket-Version: 13\r\n"
        f"Sec-WebSocket-Protocol: posecast.v1\r\n\r\n".encode()
    )
    head = b""
    while b"\r\n\r\n" not in head:
        head += s.recv(1)
    assert head.startswith(b"HTTP/1.1 101"), head
    got = [0]

    def drain() -> None:
        with contextlib.suppress(OSError):
            while data := s.recv(1 << 16):
                got[0] += len(data)

    reader = threading.Thread(target=drain, daemon=True)
    if read:
        reader.start()
    chunk, sent = PING * 500, 0
    s.settimeout(0.2)
    t0 = time.monotonic()
    while time.monotonic() - t0 < seconds:
        with contextlib.suppress(TimeoutError):
            s.sendall(chunk)
            sent += len(chunk)
    if read:
        time.sleep(0.5)  # the last pongs
    s.close()
    return {"sent": sent // len(PING), "pongs": got[0] // PONG_BYTES}


def _run_flooder(arena: Arena, seconds: float, read: bool) -> tuple[dict[str, int], float]:
    """The flooder's report, and the server's peak RSS growth (MiB) while it ran."""
    assert arena.server is not None
    rss0 = peak = arena.server.rss_bytes()
    proc = subprocess.Popen(
        [sys.executable, "-m", "tests.system.reliability.test_hostile_control_frames",
         str(arena.port), str(seconds), "1" if read else "0"],
        cwd=REPO, stdout=subprocess.PIPE, text=True,
        preexec_fn=lambda: os.nice(ATTACKER_NICE),
    )  # fmt: skip
    while proc.poll() is None:
        peak = max(peak, arena.server.rss_bytes())
        time.sleep(0.05)
    out, _ = proc.communicate()
    assert proc.returncode == 0
    report: dict[str, int] = json.loads(out)
    return report, (peak - rss0) / 2**20


def _paced(port: int) -> float:
    return scrape(port).get(("posecast_reads_paced_total", ()), 0.0)


def test_a_ping_frame_flood_is_paced_and_nobody_else_notices(arena: Arena) -> None:
    cfg = arena.cfg
    baseline = arena.baseline()
    paced0 = _paced(arena.port)
    t0 = time.monotonic()
    with arena.window() as during:
        report, _ = _run_flooder(arena, FLOOD_S, read=True)
    window_s = time.monotonic() - t0
    paced_hz = 2.0 * (cfg.max_rate_hz + cfg.control_rate_hz)
    paced_burst = 2.0 * (cfg.rate_burst + cfg.control_rate_hz)
    bound = paced_hz * window_s + paced_burst + ONE_READ
    print(f"ping frames: {report['sent']} sent in {FLOOD_S} s, {report['pongs']} answered "
          f"(bound {bound:.0f}); reads paused {_paced(arena.port) - paced0:.0f} times")  # fmt: skip
    # Each ping read is answered: what was answered is what the server read.
    assert report["pongs"] <= bound, "ping frames were not paced"
    assert _paced(arena.port) - paced0 >= 1
    assert arena.server is not None and arena.server.alive()
    for player in arena.clients:
        assert arena.errors_of(player) == []
    assert_rates_kept(during[0], baseline, "ping-frame flood")


def test_pongs_a_flooder_does_not_read_do_not_pile_up_in_the_server(arena: Arena) -> None:
    report, grown_mib = _run_flooder(arena, FLOOD_S, read=False)
    print(f"ping frames, pongs unread: {report['sent']} sent; server RSS +{grown_mib:.1f} MiB")
    assert grown_mib < 16.0  # unpaced: +36 MiB in 4 s here, and growing without bound
    assert arena.server is not None and arena.server.alive()


if __name__ == "__main__":
    port, seconds, read = int(sys.argv[1]), float(sys.argv[2]), sys.argv[3] == "1"
    print(json.dumps(_flood(port, seconds, read)))
