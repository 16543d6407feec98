"""Test helpers: a scripted posecast peer in this process (websockets), and a
loopback URL nothing listens on. The client's error paths run against them
(``test_dial.py``, ``test_link.py``, ``test_cli.py``)."""

from __future__ import annotations

import contextlib
import socket
from collections.abc import AsyncIterator, Callable

from websockets.asyncio.server import Server, ServerConnection, serve
from websockets.exceptions import ConnectionClosed
from websockets.http11 import Request, Response

from posecast_client.codec import decode, encode
from posecast_client.protocol import Hello, Limits, Member, Welcome


def refused_url() -> str:
    """A loopback URL nothing listens on: a port bound, then closed."""
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    return f"ws://127.0.0.1:{port}/"


def url_of(server: Server, scheme: str = "ws") -> str:
    port = next(iter(server.sockets)).getsockname()[1]
    return f"{scheme}://127.0.0.1:{port}/"


@contextlib.asynccontextmanager
async def peer(
    on_hello: str = "welcome",
    refuse: Callable[[], int | None] = lambda: None,
    paths: list[str] | None = None,
) -> AsyncIterator[Server]:
    """A posecast v1 server in this process. ``on_hello``: ``welcome`` (join), ``drop``
    (welcome, then close), ``close`` (close without a word) or ``silent`` (say nothing).
    ``refuse``: an HTTP status to refuse the upgrade with, asked at every connection
    (None: go on). ``paths``: gets each upgrade request's path."""

    def gate(conn: ServerConnection, request: Request) -> Response | None:
        if paths is not None:
            paths.append(request.path)
        status = refuse()
        return None if status is None else conn.respond(status, "too many connection attempts\n")

    async def handler(ws: ServerConnection) -> None:
        with contextlib.suppress(ConnectionClosed):
            async for data in ws:
                msg = decode(data if isinstance(data, bytes) else data.encode())
                if not isinstance(msg, Hello):
                    continue
                if on_hello == "close":
                    await ws.close()
                elif on_hello in ("welcome", "drop"):
                    members = (Member("p1", msg.name),)
                    welcome = Welcome(1, "p1", "s1", "player", msg.room, 0.0, 60.0, 2, members,
                                      Limits())  # fmt: skip
                    await ws.send(encode(welcome))
                    if on_hello == "drop":
                        await ws.close()

    async with serve(handler, "127.0.0.1", 0, subprotocols=["posecast.v1"],  # type: ignore[list-item]
                     process_request=gate) as server:  # fmt: skip
        yield server
