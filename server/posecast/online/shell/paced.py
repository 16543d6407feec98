"""Read budgets: what one connection may have parsed, counted before websockets parses it.

websockets parses every frame of a socket read, and answers each ping in it, before
anything reaches the server's handler: a 256 KiB read holds 43,690 empty pings. A
budget counted after that parse bounds nothing, so :class:`FrameScanner` walks the
RFC 6455 frame *headers* of the bytes that arrived (a few operations a frame, no
payload touched) and :class:`PacedConnection` hands websockets only the frames and
bytes the connection's budgets allow, keeping the rest of the read until they allow
more, with the socket's reading paused (the flood then waits in the flooder's own
buffers and TCP window).

Three budgets per connection (:class:`ReadBudget`), each a token bucket:

* **frames**, any opcode (data, continuation, ping, pong, close);
* **control frames** (ping, pong, close), which cost a frame each and a pong's write;
* **bytes**, headers and payloads.

Before ``hello`` they are small (a client owes one message); after it they are twice
what the protocol allows a player (frames plus control messages). The figures
behind them, microseconds a frame and nanoseconds a byte, are from
``benchmarks/frame_cost.py``; docs/reliability.md ("Read budgets") gives them.

A connection held back by its budget for :data:`FLOOD_CUTOFF_S` on end (2-3 s, drawn
per connection; a conforming client never is: the budget is twice its allowance) is
reported through ``flooded``, and the server cuts it off with ``RATE_LIMITED``,
charged to its address.
"""

from __future__ import annotations

import asyncio
import random
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from websockets.asyncio.server import ServerConnection
from websockets.protocol import State

from posecast.online.core.ratelimit import SocketCount, TokenBucket

FLOOD_CUTOFF_S = 2.0  # held back this long without a break: cut off (RATE_LIMITED) ...
FLOOD_CUTOFF_SPREAD = 0.5  # ... or up to this share longer, at random per connection
# The draws' own generator: the module-level one is the process's (a test framework
# that seeds or watches it, Hypothesis, must not see the server draw from it).
_CUTOFF_DRAW = random.Random()
RESUME_S = 0.05  # a held-back connection is read again once this much budget is back
PRE_HELLO_FRAMES_HZ = 4.0  # before hello: a client owes one message (hello)
PRE_HELLO_FRAMES_BURST = 8.0
CONTROL_FRAMES_HZ = 2.0  # pings, pongs, closes: a client's keep-alive is one per 20 s
CONTROL_FRAMES_BURST = 8.0
MAX_HEAD_BYTES = 16 * 1024  # an HTTP request head held whole before websockets reads it
_BAD_BODY = b"a request to this server carries no body\n"
_BAD_REQUEST = (
    b"HTTP/1.1 400 Bad Request\r\nConnection: close\r\nContent-Type: text/plain\r\n"
    b"Content-Length: %d\r\n\r\n%s" % (len(_BAD_BODY), _BAD_BODY)
)


def _has_body(head: bytes) -> bool:
    """Whether an HTTP/1.1 request head announces a body (RFC 9112, section 6.3)."""
    for line in head.split(b"\r\n")[1:]:
        name, _, value = line.partition(b":")
        name = name.strip().lower()
        if name == b"transfer-encoding":
            return True
        if name == b"content-length" and value.strip() not in (b"0", b""):
            return True
    return False


@dataclass(frozen=True)
class Budget:
    """Rates (per second) and bursts of one phase of a connection."""

    frames_hz: float
    frames_burst: float
    bytes_hz: float
    bytes_burst: float
    control_hz: float = CONTROL_FRAMES_HZ
    control_burst: float = CONTROL_FRAMES_BURST


@dataclass(frozen=True)
class Budgets:
    """A connection's budget before ``hello`` and once joined."""

    before_hello: Budget
    joined: Budget

    @classmethod
    def for_limits(
        cls,
        *,
        max_rate_hz: float,
        rate_burst: float,
        control_rate_hz: float,
        max_frame_bytes: int,
        max_message_bytes: int,
    ) -> Budgets:
        """Twice the protocol's allowance once joined (frames and control messages);
        before ``hello`` a few frames, and bytes enough for the largest frame at once.
        Bytes cost about 0.3-1.6 ns each against 4-10 us a frame (frame_cost.py), so
        their budget bounds memory and a frame's worth of unmasking, not the CPU."""
        frames_hz = 2.0 * (max_rate_hz + control_rate_hz)
        return cls(
            before_hello=Budget(
                PRE_HELLO_FRAMES_HZ, PRE_HELLO_FRAMES_BURST, max_frame_bytes, max_frame_bytes
            ),
            joined=Budget(
                frames_hz,
                2.0 * (rate_burst + control_rate_hz),
                frames_hz * max_message_bytes,
                2.0 * max_frame_bytes,
            ),
        )


class ReadBudget:
    """The three buckets of one connection; :meth:`allowance` and :meth:`spend`."""

    def __init__(self, budget: Budget, now: float) -> None:
        self.frames = TokenBucket(budget.frames_hz, budget.frames_burst)
        self.control = TokenBucket(budget.control_hz, budget.control_burst)
        self.bytes = TokenBucket(budget.bytes_hz, budget.bytes_burst)

    def raised(self, budget: Budget, now: float) -> ReadBudget:
        """The same connection on ``budget`` from ``now``: faster rates and larger
        bursts, but only the tokens it had saved, not a full burst (a hundred flooders
        admitted together would each be handed a hundred frames at once)."""
        out = ReadBudget(budget, now)
        for old, new in ((self.frames, out.frames), (self.control, out.control),
                         (self.bytes, out.bytes)):  # fmt: skip
            new.tokens, new.stamp = min(new.burst, old.available(now)), now
        return out

    def allowance(self, now: float) -> tuple[int, int, int]:
        """Whole frames, control frames and bytes that may be read now."""
        return (
            max(0, int(self.frames.available(now))),
            max(0, int(self.control.available(now))),
            max(0, int(self.bytes.available(now))),
        )

    def spend(self, now: float, frames: int, control: int, nbytes: int) -> None:
        self.frames.take(now, frames)
        self.control.take(now, control)
        self.bytes.take(now, nbytes)

    def wait_s(self, limited_by: str) -> float:
        """Seconds until ``limited_by``'s bucket has :data:`RESUME_S` of its rate back
        (at least one token, at most its burst)."""
        bucket = {"frames": self.frames, "control": self.control, "bytes": self.bytes}[limited_by]
        want = min(bucket.burst, max(1.0, bucket.rate_hz * RESUME_S))
        return max(0.0, (want - bucket.tokens) / bucket.rate_hz)


class FrameScanner:
    """Walks the frame headers of a client's byte stream (RFC 6455, section 5.2),
    without reading or unmasking payloads; the state carries over between reads."""

    def __init__(self) -> None:
        self.left = 0  # payload bytes of the current frame not yet passed

    def scan(
        self, buf: bytes | bytearray, frames: int, control: int, nbytes: int
    ) -> tuple[int, int, int, str | None]:
        """How much of ``buf`` may be passed on: at most ``frames`` new frames (of them
        at most ``control`` control frames) and ``nbytes`` bytes; a header is passed
        whole or not at all. Returns ``(end, frames, control frames, limited_by)``,
        ``limited_by`` the budget that stopped the scan (``None``: all of ``buf``
        may pass, or what is left is the start of a header that needs more bytes)."""
        i, end, n_frames, n_control = 0, len(buf), 0, 0
        stop = min(end, nbytes)
        while i < end:
            if self.left:
                take = min(self.left, stop - i)
                if take <= 0:
                    return i, n_frames, n_control, "bytes"
                i += take
                self.left -= take
                continue
            if end - i < 2:
                break
            b0, b1 = buf[i], buf[i + 1]
            code = b1 & 0x7F
            head = (2, 4, 10)[(code >= 126) + (code == 127)] + (4 if b1 & 0x80 else 0)
            if end - i < head:
                break
            is_control = bool(b0 & 0x08)  # opcodes 8-15
            if n_frames >= frames:
                return i, n_frames, n_control, "frames"
            if is_control and n_control >= control:
                return i, n_frames, n_control, "control"
            if i + head > stop:
                return i, n_frames, n_control, "bytes"
            if code == 126:
                code = int.from_bytes(buf[i + 2 : i + 4], "big")
            elif code == 127:
                code = int.from_bytes(buf[i + 2 : i + 10], "big")
            n_frames += 1
            n_control += is_control
            i += head
            self.left = code
        return i, n_frames, n_control, None


class PacedConnection(ServerConnection):
    """A ``ServerConnection`` that lets websockets parse only what its
    :class:`ReadBudget` allows (``paced`` counts each time it holds a read back), and
    that is dropped at once when its address already holds ``sockets.per_ip`` sockets
    (``refused``): sockets that connect and send nothing reach no HTTP check, and each
    held a coroutine and a file descriptor until the opening handshake timed out.

    The server calls :meth:`joined` once the connection's ``hello`` is admitted (the
    joined budget from then on) and sets :attr:`flooded`, called once when the
    connection has been held back for :data:`FLOOD_CUTOFF_S` on end.

    Reading resumes only when both allow it: the budget, and websockets' queue of
    messages (which pauses reading above its high mark and resumes it below its low
    one, and would otherwise resume a held-back read as soon as the handler drained it).
    :func:`paced_connection` makes the class for one server (its budgets and counters).
    """

    budgets: Budgets
    paced: Callable[[], None]
    sockets: SocketCount
    refused: Callable[[], None]
    bad_request: Callable[[], None]
    clock: Callable[[], float]
    flooded: Callable[[], None] | None = None

    def connection_made(self, transport: asyncio.BaseTransport) -> None:
        super().connection_made(transport)
        self.budget = ReadBudget(self.budgets.before_hello, self.clock())
        self.before_hello = True
        self.scanner = FrameScanner()
        self.held = b""  # read from the socket, not yet passed to websockets
        self.held_back_since: float | None = None
        # Flooders that connected together are cut off over a second, not in one
        # instant: their reconnections (a handshake each) then come spread out too.
        self.cutoff_s = FLOOD_CUTOFF_S * (1.0 + FLOOD_CUTOFF_SPREAD * _CUTOFF_DRAW.random())
        self.request_head: bytes | None = b""  # the HTTP request read so far (None: passed)
        self.oversized = False  # a request head past MAX_HEAD_BYTES: websockets' to refuse
        self.read_again: asyncio.TimerHandle | None = None
        self.recv_messages.resume = self._queue_drained
        peer = transport.get_extra_info("peername")
        self.counted = str(peer[0]) if isinstance(peer, tuple) and peer else None
        if self.counted is not None and not self.sockets.open(self.counted):
            self.counted = None
            self.refused()
            self.transport.abort()  # the handshake fails at once; connection_lost follows

    def joined(self) -> None:
        """The ``hello`` was admitted: the joined budget from now on (with the tokens
        saved before it, :meth:`ReadBudget.raised`)."""
        self.budget = self.budget.raised(self.budgets.joined, self.clock())
        self.before_hello = False

    async def handshake(self, *args: Any, **kwargs: Any) -> None:
        await super().handshake(*args, **kwargs)
        self._read_again()  # frames that came with the request, held until now

    def data_received(self, data: bytes) -> None:
        if self.oversized:  # websockets refuses the request and discards the rest
            super().data_received(data)
            return
        if self.request_head is not None:  # still reading the HTTP request
            data = self._request(data)
            if not data:
                return
        self.held = self.held + data if self.held else data
        self._pass()

    def _request(self, data: bytes) -> bytes:
        """The HTTP request goes to websockets whole, once its blank line is in; what
        follows it is frames, returned, to wait for the handshake's end. A request
        with a body is answered 400 here (websockets would close without a word);
        a head past :data:`MAX_HEAD_BYTES` goes on as it is, for websockets to refuse."""
        assert self.request_head is not None
        head = self.request_head + data
        blank = head.find(b"\r\n\r\n")
        if blank < 0:
            if len(head) > MAX_HEAD_BYTES:
                self.request_head, self.oversized = None, True
                super().data_received(head)
            else:
                self.request_head = head
            return b""
        self.request_head = None
        if _has_body(head[:blank]):
            self.bad_request()
            self.transport.write(_BAD_REQUEST)
            self.transport.close()
            return b""
        super().data_received(head[: blank + 4])
        return head[blank + 4 :]

    def _pass(self) -> None:
        """Hand websockets what the budget allows of :attr:`held`."""
        if self.protocol.state is State.CONNECTING:
            self.transport.pause_reading()  # until the handshake ends
            return
        now = self.clock()
        frames, control, nbytes = self.budget.allowance(now)
        end, n_frames, n_control, limited_by = self.scanner.scan(self.held, frames, control, nbytes)
        self.budget.spend(now, n_frames, n_control, end)
        if end:
            chunk = self.held if end == len(self.held) else self.held[:end]
            self.held = self.held[end:]
            super().data_received(chunk)
        if limited_by is None:
            self.held_back_since = None
            return
        self.paced()
        if self.held_back_since is None:
            self.held_back_since = now
        elif now - self.held_back_since >= self.cutoff_s and self.flooded is not None:
            flooded, self.flooded = self.flooded, None
            flooded()
        self.transport.pause_reading()
        if self.read_again is not None:
            self.read_again.cancel()
        self.read_again = self.loop.call_later(self.budget.wait_s(limited_by), self._read_again)

    def _read_again(self) -> None:
        self.read_again = None
        if self.transport.is_closing():
            return
        if self.held:
            self._pass()
        if self.read_again is None and not self.recv_messages.paused:
            self.transport.resume_reading()

    def _queue_drained(self) -> None:
        if self.read_again is None:  # else the budget resumes reading when it allows
            self.transport.resume_reading()

    def connection_lost(self, exc: Exception | None) -> None:
        self.held = b""
        if self.read_again is not None:
            self.read_again.cancel()
        if self.counted is not None:
            self.sockets.close(self.counted)
            self.counted = None
        super().connection_lost(exc)


def paced_connection(
    budgets: Budgets,
    *,
    paced: Callable[[], None],
    sockets: SocketCount,
    refused: Callable[[], None],
    bad_request: Callable[[], None] = lambda: None,
    clock: Callable[[], float] = time.monotonic,
) -> type[PacedConnection]:
    """The :class:`PacedConnection` class of one server: its budgets and counters."""
    return type(
        "ServerPacedConnection",
        (PacedConnection,),
        {
            "budgets": budgets,
            "paced": staticmethod(paced),
            "sockets": sockets,
            "refused": staticmethod(refused),
            "bad_request": staticmethod(bad_request),
            "clock": staticmethod(clock),
        },
    )
