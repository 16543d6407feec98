"""Helpers of the fault-injection tests: a ``posecast serve`` subprocess
(:class:`posecast.testing.serve.ServeProcess`) with RSS sampling, a raw client that
never reads, and the measures the tests report (pose rates, gaps, joint jumps, lost
poses). The lossy relay the network tests put between a client and the server is
:mod:`posecast.testing.relay` (``posecast bench latency`` runs it too).

Everything runs on loopback against real processes; nothing here fakes the server.
"""

from __future__ import annotations

import base64
import contextlib
import itertools
import os
import socket
import struct
import threading
import time
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from websockets.asyncio.client import ClientConnection

from posecast.online.protocol import encode
from posecast.online.protocol.messages import SUBPROTOCOL, Frame, Hello, Message, Pose
from posecast.testing.serve import ServeProcess, rss_bytes
from posecast.tracking.layouts import Layout
from tests.online.conftest import SECRET

TICK_HZ = 60.0  # the server default the tests run at


# --- the server under test ---------------------------------------------------------------


class ServerProc(ServeProcess):
    """One ``posecast serve`` subprocess on an ephemeral loopback port (8 samples,
    look-ahead 2, only the ``hmd3+waist`` layout: one model to load, a faster start),
    with per-IP connection and fatal-error budgets these reconnecting tests never
    spend. A :class:`~posecast.testing.serve.ServeProcess`.

    ``log`` (optional) receives the server's JSON log lines (stderr).
    """

    def __init__(self, *extra: str, log: Path | None = None, log_level: str = "WARNING") -> None:
        super().__init__(
            "--conn-per-ip-per-min", "100000", "--fatal-per-ip-per-min", "100000",
            "--sockets-per-ip", "100000", *extra,
            secret=SECRET, samples=8, lookahead=2, log=log, log_level=log_level,
            env={"POSECAST_LAYOUTS": Layout.HMD3_WAIST.value},
        )  # fmt: skip

    def rss_kib(self) -> int:
        return rss_kib(self.pid)

    def close(self) -> None:
        self.stop(timeout_s=15)


def rss_kib(pid: int) -> int:
    """Resident set size of process ``pid``, KiB (Linux ``/proc``)."""
    return rss_bytes(pid) // 1024


class RssSampler:
    """Samples a process's RSS every ``period_s`` in a thread: ``(monotonic, KiB)``."""

    def __init__(self, pid: int, period_s: float = 0.1) -> None:
        self.pid, self.period_s = pid, period_s
        self.samples: list[tuple[float, int]] = []
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()

    def _run(self) -> None:
        while not self._stop.is_set():
            with contextlib.suppress(OSError, RuntimeError):  # the process may be gone
                self.samples.append((time.monotonic(), rss_kib(self.pid)))
            self._stop.wait(self.period_s)

    def stop(self) -> None:
        self._stop.set()
        self._thread.join(5)

    def between(self, t0: float, t1: float) -> list[int]:
        return [kib for t, kib in self.samples if t0 <= t <= t1]


# --- a client that never reads -------------------------------------------------------------


def _masked_frame(payload: bytes, opcode: int = 0x2) -> bytes:
    """One client-to-server WebSocket frame (FIN, masked, as RFC 6455 requires)."""
    n = len(payload)
    if n < 126:
        head = struct.pack("!BB", 0x80 | opcode, 0x80 | n)
    elif n < 65536:
        head = struct.pack("!BBH", 0x80 | opcode, 0x80 | 126, n)
    else:
        head = struct.pack("!BBQ", 0x80 | opcode, 0x80 | 127, n)
    mask = os.urandom(4)
    body = bytes(b ^ mask[i % 4] for i, b in enumerate(payload))
    return head + mask + body


class SilentReader:
    """A raw TCP client that completes the WebSocket handshake, sends ``hello`` (and,
    if asked, frames) and never reads another byte. Its receive buffer is made small
    (``rcvbuf_bytes``, set before connecting) so the server's side fills quickly."""

    def __init__(self, port: int, tok: str, room: str, name: str, rcvbuf_bytes: int = 4096):
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
        self.sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, rcvbuf_bytes)
        self.sock.connect(("127.0.0.1", port))
        key = base64.b64encode(os.urandom(16)).decode()
        self.sock.sendall(
            (
                "GET / HTTP/1.1\r\nHost: 127.0.0.1\r\nUpgrade: websocket\r\n"
                f"Connection: Upgrade\r\nSec-WebSocket-Key: {key}\r\n"
                f"Sec-WebSocket-Version: 13\r\nSec-WebSocket-Protocol: {SUBPROTOCOL}\r\n\r\n"
            ).encode()
        )
        head = b""
        while b"\r\n\r\n" not in head:  # the 101 response, byte by byte: nothing more
            chunk = self.sock.recv(1)
            assert chunk, f"the server closed during the handshake: {head!r}"
            head += chunk
        assert head.startswith(b"HTTP/1.1 101"), head
        self.sock.sendall(_masked_frame(encode(Hello(1, tok, room, name))))
        self.hello_at = time.monotonic()
        self.sock.setblocking(False)

    def send_nowait(self, msg: Frame) -> bool:
        """Send one message if the socket takes it whole right now."""
        data = _masked_frame(encode(msg))
        try:
            sent = self.sock.send(data)
        except (BlockingIOError, OSError):
            return False
        assert sent == len(data), "a partial frame would corrupt the stream"
        return True

    def tcp_state(self) -> int:
        """The kernel's TCP state (1: ESTABLISHED; 7: CLOSE, e.g. after a reset)."""
        info = self.sock.getsockopt(socket.IPPROTO_TCP, socket.TCP_INFO, 8)
        return info[0]

    def reset_by_server(self) -> bool:
        """The server dropped the connection (RST or FIN received)."""
        return self.tcp_state() != 1

    def close(self) -> None:
        self.sock.close()


def abort_with_reset(ws: ClientConnection) -> None:
    """Vanish: ``SO_LINGER`` 0 then close, so the kernel sends a TCP RST and no
    WebSocket close frame ever leaves."""
    sock = ws.transport.get_extra_info("socket")
    sock.setsockopt(socket.SOL_SOCKET, socket.SO_LINGER, struct.pack("ii", 1, 0))
    ws.transport.abort()


# --- measures -------------------------------------------------------------------------------


def rates_hz(poses: Sequence[Pose], t0: float, t1: float, window_s: float = 0.5) -> list[float]:
    """Poses per second in consecutive windows of server time ``[t0, t1)``."""
    n = max(1, int((t1 - t0) / window_s))
    counts = [0] * n
    for p in poses:
        k = int((p.t - t0) / window_s)
        if 0 <= k < n:
            counts[k] += 1
    return [c / window_s for c in counts]


def max_gap_s(poses: Sequence[Pose]) -> float:
    """Longest server-time gap between consecutive poses of one player."""
    ts = [p.t for p in poses]
    return max((b - a for a, b in itertools.pairwise(ts)), default=0.0)


def server_gap_s(poses: Sequence[Pose], sent_at: dict[int, float]) -> float:
    """The longest gap between consecutive poses of one player that the server added:
    each server-time gap minus the gap between the sending of those two frames
    (``sent_at``: seq -> when its sender sent it, the same monotonic clock). A stall
    of the sending client (a GC pause in the test process) is the client's, not the
    server's, and cancels out."""
    gaps = (
        (b.t - a.t) - (sent_at[b.seq] - sent_at[a.seq])
        for a, b in itertools.pairwise(poses)
        if a.seq in sent_at and b.seq in sent_at
    )
    return max(gaps, default=0.0)


@dataclass(frozen=True)
class Jumps:
    max_jump_m: float  # largest joint displacement between consecutive poses
    max_speed_m_s: float  # the same divided by the server time between them
    p99_jump_m: float


def joint_jumps(poses: Sequence[Pose]) -> Jumps:
    """How far any joint moves between consecutive poses (one player, in order)."""
    if len(poses) < 2:
        return Jumps(0.0, 0.0, 0.0)
    pos = np.stack([p.positions for p in poses])  # (P, 19, 3)
    t = np.array([p.t for p in poses])  # (P,)
    step = np.linalg.norm(np.diff(pos, axis=0), axis=-1).max(axis=-1)  # (P-1,)
    dt = np.maximum(np.diff(t), 1.0 / TICK_HZ)
    return Jumps(float(step.max()), float((step / dt).max()), float(np.percentile(step, 99)))


def seqs_in(poses: Iterable[Pose], t0: float, t1: float) -> set[tuple[str, int]]:
    """``(player, seq)`` of the poses made by ticks in ``[t0, t1]`` (server time)."""
    return {(p.player, p.seq) for p in poses if t0 <= p.t <= t1}


def pose_of(player: str) -> Callable[[Message], bool]:
    """A ``wait_for`` predicate: a pose of ``player``."""
    return lambda m: isinstance(m, Pose) and m.player == player


def is_(expected: Message) -> Callable[[Message], bool]:
    """A ``wait_for`` predicate: a message equal to ``expected``."""
    return lambda m: m == expected


def fmt(values: Iterable[float], digits: int = 1) -> str:
    return "[" + ", ".join(f"{v:.{digits}f}" for v in values) + "]"


def report(title: str, **figures: Any) -> None:
    """Print one line of figures (``pytest -s`` shows them; CI logs keep them)."""
    body = "  ".join(f"{k}={v}" for k, v in figures.items())
    print(f"\n[fault] {title}: {body}")
