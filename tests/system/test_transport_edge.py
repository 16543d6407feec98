"""The WebSocket layer's own refusals (posecast.online.shell.app): frames that websockets
refuses before any message reaches the codec, and control frames, which websockets
answers itself. A real server on loopback; the bad frames are written by hand."""

from __future__ import annotations

import asyncio
import base64
import contextlib
import os
import struct
import time
from collections.abc import Coroutine
from typing import Any

import pytest
from websockets.exceptions import InvalidMessage, InvalidStatus

from posecast.online.protocol import decode, encode
from posecast.online.protocol.messages import Error, Hello, Ping, Welcome
from posecast.online.shell.paced import CONTROL_FRAMES_BURST, CONTROL_FRAMES_HZ, FLOOD_CUTOFF_S
from tests.online.conftest import make_cfg, token
from tests.online.wsclient import Client, Factory, serving

pytestmark = pytest.mark.timeout(60)


def run(coro: Coroutine[Any, Any, None]) -> None:
    asyncio.run(coro)


def _frame(opcode: int, payload: bytes, *, fin: bool = True, masked: bool = True) -> bytes:
    """One client frame (zero masking key: the payload goes as is)."""
    assert len(payload) < 126
    head = bytes([(0x80 if fin else 0) | opcode, (0x80 if masked else 0) | len(payload)])
    return head + (b"\0\0\0\0" if masked else b"") + payload


async def _raw(port: int) -> tuple[asyncio.StreamReader, asyncio.StreamWriter]:
    reader, writer = await asyncio.open_connection("127.0.0.1", port)
    key = base64.b64encode(os.urandom(16)).decode()
    writer.write(
        f"GET / HTTP/1.1\r\nHost: x\r\nUpgrade: websocket\r\nConnection: Upgrade\r\n"
        f"Sec-WebSocket-Key: {key}\r\nSec-WebSocket-Version: 13\r\n"
        f"Sec-WebSocket-Protocol: posecast.v1\r\n\r\n".encode()
    )
    head = await reader.readuntil(b"\r\n\r\n")
    assert head.startswith(b"HTTP/1.1 101"), head
    return reader, writer


async def _server_frame(reader: asyncio.StreamReader) -> tuple[int, bytes]:
    """The next frame the server sent: its opcode and payload."""
    b0, b1 = await reader.readexactly(2)
    n = b1 & 0x7F
    if n == 126:
        (n,) = struct.unpack("!H", await reader.readexactly(2))
    elif n == 127:
        (n,) = struct.unpack("!Q", await reader.readexactly(8))
    return b0 & 0x0F, await reader.readexactly(n)


async def _close_code(reader: asyncio.StreamReader) -> int:
    """Read server frames up to its close frame: that frame's close code."""
    while True:
        opcode, payload = await _server_frame(reader)
        if opcode == 0x8:
            code: int = struct.unpack("!H", payload[:2])[0]
            return code


BAD_FRAMES = {  # what each breaks, and the close code websockets answers it with
    "text that is not UTF-8": (_frame(0x1, b"\xff\xfe"), 1007),
    "an unmasked frame": (_frame(0x2, b"abc", masked=False), 1002),
    "RSV1 set (no extension)": (bytes([0xC2, 0x83]) + b"\0\0\0\0abc", 1002),
    "a continuation with no start": (_frame(0x0, b"abc"), 1002),
    "a reserved opcode": (_frame(0x3, b"abc"), 1002),
    "a fragmented ping": (_frame(0x9, b"x", fin=False), 1002),
}


def test_frames_websockets_refuses_are_counted_and_charged_as_malformed(
    engine_factory: Factory,
) -> None:
    """Each closed its session (1002 / 1007) with nothing counted and nothing charged to
    the address's fatal budget, so a client could join, send one, and come back again
    without ever meeting the budget's 429."""

    async def scenario() -> None:
        n = len(BAD_FRAMES)
        async with serving(make_cfg(fatal_per_ip_per_min=n), engine_factory) as server:
            for i, (what, (data, code)) in enumerate(BAD_FRAMES.items()):
                reader, writer = await _raw(server.port)
                hello = encode(Hello(1, token(player=f"p{i}"), "r1", "Ann"))
                writer.write(b"\x82\xfe" + struct.pack("!H", len(hello)) + b"\0\0\0\0" + hello)
                writer.write(data)
                assert await asyncio.wait_for(_close_code(reader), 5) == code, what
                writer.close()
            deadline = time.monotonic() + 5
            counted = server.metrics.value("posecast_errors_total", {"code": "MALFORMED"})
            while counted < n and time.monotonic() < deadline:
                await asyncio.sleep(0.02)
                counted = server.metrics.value("posecast_errors_total", {"code": "MALFORMED"})
            assert counted == n
            with pytest.raises(InvalidStatus) as e:  # the address's budget is spent
                await Client.open(server.port)
            assert e.value.response.status_code == 429

    run(scenario())


def test_a_close_the_client_begins_is_not_an_error_of_the_client(
    engine_factory: Factory,
) -> None:
    """A client that closes with 1009 (a server message too big for it) or 1002 says
    something about the server: nothing is counted or charged against it."""

    async def scenario() -> None:
        async with serving(make_cfg(fatal_per_ip_per_min=1), engine_factory) as server:
            for i, code in enumerate((1009, 1002, 1009)):
                cl = await Client.open(server.port)
                assert isinstance(await cl.hello(token(player=f"c{i}")), Welcome)
                await cl.ws.close(code, "from the client")
                await asyncio.wait_for(cl.closed.wait(), 5)
            await asyncio.sleep(0.1)
            for code in ("TOO_LARGE", "MALFORMED"):
                assert server.metrics.value("posecast_errors_total", {"code": code}) == 0
            last = await Client.open(server.port)  # the budget of 1 is untouched
            assert isinstance(await last.hello(token(player="last")), Welcome)
            await last.close()

    run(scenario())


async def _frames_until_closed(
    reader: asyncio.StreamReader, timeout_s: float
) -> tuple[int, list[str]]:
    """Pongs the server sent, and the codes of its error messages, until it closed (or
    ``timeout_s`` passed without a frame)."""
    pongs, codes = 0, []
    with contextlib.suppress(TimeoutError, asyncio.IncompleteReadError, ConnectionError):
        while True:
            opcode, payload = await asyncio.wait_for(_server_frame(reader), timeout_s)
            pongs += opcode == 0xA
            if opcode == 0x2:
                msg = decode(payload)
                if isinstance(msg, Error):
                    codes.append(msg.code)
            if opcode == 0x8:
                break
    return pongs, codes


def test_ping_frames_are_counted_before_they_are_parsed(engine_factory: Factory) -> None:
    """websockets parses a whole socket read, and answers every ping in it, before any
    message reaches the handler: 256 KiB holds 2,000 pings of 125 bytes (43,690 empty
    ones). The read budget counts frames from their headers before websockets sees
    them: before hello, a client's control frames are read at CONTROL_FRAMES_HZ with a
    burst of CONTROL_FRAMES_BURST, whatever one read holds; and a client held back
    for FLOOD_CUTOFF_S on end is cut off with RATE_LIMITED, counted."""

    async def scenario() -> None:
        async with serving(make_cfg(), engine_factory) as server:
            reader, writer = await _raw(server.port)
            t0 = time.monotonic()
            writer.write(_frame(0x9, b"x" * 125) * 8000)  # 1 MiB of pings
            pongs, codes = await _frames_until_closed(reader, 5.0)
            window_s = time.monotonic() - t0
            assert 0 < pongs <= CONTROL_FRAMES_BURST + CONTROL_FRAMES_HZ * window_s
            assert codes == ["RATE_LIMITED"]
            assert FLOOD_CUTOFF_S <= window_s < FLOOD_CUTOFF_S + 3.0
            assert server.metrics.value("posecast_reads_paced_total") >= 1
            assert server.metrics.value("posecast_floods_cut_off_total") == 1
            writer.transport.abort()

    run(scenario())


@pytest.mark.parametrize("apart", [False, True])
def test_frames_sent_with_the_upgrade_request_wait_for_the_budget(
    engine_factory: Factory, apart: bool
) -> None:
    """Frames that ride in the same socket read as the HTTP request, or come in the
    next read before the handshake is over (``apart``), are not parsed with it: they
    wait for the handshake's end and then for the budget, as any other."""

    async def scenario() -> None:
        async with serving(make_cfg(), engine_factory) as server:
            reader, writer = await asyncio.open_connection("127.0.0.1", server.port)
            key = base64.b64encode(os.urandom(16)).decode()
            request = (
                f"GET / HTTP/1.1\r\nHost: x\r\nUpgrade: websocket\r\nConnection: Upgrade\r\n"
                f"Sec-WebSocket-Key: {key}\r\nSec-WebSocket-Version: 13\r\n"
                f"Sec-WebSocket-Protocol: posecast.v1\r\n\r\n"
            ).encode()
            pings = _frame(0x9, b"") * 40_000  # 240 kB of empty pings
            if apart:
                writer.write(request)
                await writer.drain()
                writer.write(pings)
            else:
                writer.write(request + pings)
            head = await reader.readuntil(b"\r\n\r\n")
            assert head.startswith(b"HTTP/1.1 101"), head
            t0 = time.monotonic()
            pongs, codes = await _frames_until_closed(reader, 5.0)
            window_s = time.monotonic() - t0
            assert 0 < pongs <= CONTROL_FRAMES_BURST + CONTROL_FRAMES_HZ * window_s
            assert codes == ["RATE_LIMITED"]
            writer.transport.abort()

    run(scenario())


def test_pings_between_messages_stay_paced_when_the_message_queue_drains(
    engine_factory: Factory,
) -> None:
    """websockets resumes reading when its queue of messages drains below its low mark,
    which undid the read pacing's pause: a client sending a message every few hundred
    pings had each drained queue buy it another socket read, about 40,000 pings
    answered, several times a second. The queue's resume now waits for the budget,
    and a joined player's control frames keep their own budget."""

    async def scenario() -> None:
        cfg = make_cfg()
        async with serving(cfg, engine_factory) as server:
            reader, writer = await _raw(server.port)
            hello = encode(Hello(1, token(player="p"), "r1", "Ann"))
            writer.write(b"\x82\xfe" + struct.pack("!H", len(hello)) + b"\0\0\0\0" + hello)
            ping = _frame(0x9, b"")
            unit = _frame(0x2, encode(Ping(1.0))) + ping * 150  # a message, 150 pings

            async def flood() -> None:
                with contextlib.suppress(OSError):
                    while True:
                        writer.write(unit * 1000)
                        await writer.drain()

            flooding = asyncio.create_task(flood())
            t0 = time.monotonic()
            pongs, codes = await _frames_until_closed(reader, 5.0)
            window_s = time.monotonic() - t0
            flooding.cancel()
            writer.transport.abort()
            with contextlib.suppress(asyncio.CancelledError):
                await flooding
            # The before-hello burst, then the joined one, then the rate.
            bound = 2 * CONTROL_FRAMES_BURST + CONTROL_FRAMES_HZ * window_s
            assert 0 < pongs <= bound, pongs
            assert codes[-1] == "RATE_LIMITED", codes
            assert server.metrics.value("posecast_floods_cut_off_total") == 1

    run(scenario())


def test_sockets_that_send_nothing_are_capped_per_address(engine_factory: Factory) -> None:
    """A socket that connects and sends no request reaches no HTTP check (the per-IP
    attempt rate reads the request) and held a coroutine and a file descriptor until
    the opening handshake timed out, as many as one address cared to open. Past
    ``sockets_per_ip`` the server drops a new one at once; the count goes down as
    sockets close, whoever closes them."""

    async def dropped(reader: asyncio.StreamReader) -> None:
        with contextlib.suppress(ConnectionResetError):
            assert await asyncio.wait_for(reader.read(1), 10.0) == b""

    async def scenario() -> None:
        cfg = make_cfg(sockets_per_ip=4, hello_timeout_s=3.0)
        async with serving(cfg, engine_factory) as server:
            refused = {"result": "ip_sockets"}
            t0 = time.monotonic()
            idle = [await asyncio.open_connection("127.0.0.1", server.port) for _ in range(4)]
            reader, writer = await asyncio.open_connection("127.0.0.1", server.port)
            await dropped(reader)  # the fifth, at once
            assert time.monotonic() - t0 < cfg.hello_timeout_s  # not by the handshake's timeout
            writer.close()
            assert server.metrics.value("posecast_connects_total", refused) == 1
            with pytest.raises(InvalidMessage):  # a WebSocket client from there too: no response
                await Client.open(server.port)
            assert server.metrics.value("posecast_connects_total", refused) == 2
            for _, w in idle[:2]:  # closed by the client
                w.close()
            retries = 0  # until the server has seen those two close
            while True:
                try:
                    cl = await Client.open(server.port)
                    break
                except InvalidMessage:
                    retries += 1
                    assert retries < 50
                    await asyncio.sleep(0.1)
            assert isinstance(await cl.hello(token(player="p")), Welcome)
            for r, _ in idle[2:]:  # the other two time out (hello_timeout_s)
                await dropped(r)
            await asyncio.sleep(0.2)
            # cl and three more fit (their places came back); a fifth does not.
            more = [await asyncio.open_connection("127.0.0.1", server.port) for _ in range(3)]
            reader, writer = await asyncio.open_connection("127.0.0.1", server.port)
            await dropped(reader)
            assert server.metrics.value("posecast_connects_total", refused) == 3 + retries
            for _, w in more + idle + [(reader, writer)]:
                w.close()
            await cl.close()

    run(scenario())


@pytest.mark.parametrize(
    ("request_bytes", "status", "body"),
    [
        (b"GET /healthz HTTP/1.1\r\nHost: x\r\nContent-Length: 5\r\n\r\nhello", 400, b"no body"),
        (b"POST /readyz HTTP/1.1\r\nHost: x\r\nTransfer-Encoding: chunked\r\n\r\n0\r\n\r\n",
         400, b"no body"),
        (b"GET /healthz HTTP/1.1\r\nHost: x\r\n\r\nGET /readyz HTTP/1.1\r\nHost: x\r\n\r\n",
         200, b"ok\n"),
        (b"GET /healthz HTTP/1.1\r\nHost: x\r\nContent-Length: 0\r\n\r\n", 200, b"ok\n"),
        (b"GET /healthz HTTP/1.1\r\n"
         + b"".join(b"X-%d: %s\r\n" % (i, b"p" * 90) for i in range(200)) + b"\r\n",
         431, b"128 headers"),  # a head past 16 KiB: websockets' own refusal
    ],
)  # fmt: skip
def test_health_requests_with_a_body_or_pipelined_get_an_answer(
    engine_factory: Factory, request_bytes: bytes, status: int, body: bytes
) -> None:
    """A request with a body got 0 bytes back (websockets closes on one without a word),
    and so did two pipelined requests. A body is now answered 400; of pipelined
    requests the first is answered, with ``Connection: close`` (the client sends the
    rest again, RFC 9112 section 9.3.2); either way the connection then closes."""

    async def scenario() -> None:
        async with serving(make_cfg(), engine_factory) as server:
            reader, writer = await asyncio.open_connection("127.0.0.1", server.port)
            writer.write(request_bytes)
            answer = await asyncio.wait_for(reader.read(), 5.0)  # to the close
            writer.close()
            head, _, got = answer.partition(b"\r\n\r\n")
            assert head.startswith(b"HTTP/1.1 %d" % status), answer
            assert b"connection: close" in head.lower()
            assert body in got and answer.count(b"HTTP/1.1") == 1
            if status == 400:
                assert (
                    server.metrics.value("posecast_connects_total", {"result": "bad_request"}) == 1
                )

    run(scenario())
