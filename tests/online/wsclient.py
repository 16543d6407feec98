"""A small test client over the real ``websockets`` client, plus a server context.

``Client`` reads in the background (unless ``read=False``) and keeps every decoded
message, so a test can wait for the first one that matches.
"""

from __future__ import annotations

import asyncio
import contextlib
import time
from collections.abc import AsyncIterator, Callable
from typing import Any

from websockets.asyncio.client import ClientConnection, connect
from websockets.exceptions import ConnectionClosed

from posecast.online.config import ServerConfig
from posecast.online.engine.ssi import Engine
from posecast.online.protocol import decode, encode
from posecast.online.protocol.messages import (
    SUBPROTOCOL,
    SUBPROTOCOLS,
    Error,
    Hello,
    Message,
    Pose,
    Welcome,
)
from posecast.online.shell.app import PosecastServer
from tests.online.conftest import walk_frame

Factory = Callable[[ServerConfig], Callable[[], Engine]]


@contextlib.asynccontextmanager
async def serving(cfg: ServerConfig, factory: Factory) -> AsyncIterator[PosecastServer]:
    server = PosecastServer(cfg, engine_factory=factory(cfg))
    await server.start()
    try:
        yield server
    finally:
        await server.stop()


class Client:
    def __init__(self, ws: ClientConnection, read: bool, version: int = 1) -> None:
        self.ws = ws
        self.version = version
        self.messages: list[Message] = []
        self._new = asyncio.Event()
        self.closed = asyncio.Event()
        self._reader = asyncio.create_task(self._read()) if read else None
        self._sender: asyncio.Task[None] | None = None
        self.sent_at: dict[int, float] = {}  # seq -> time.monotonic() it was sent (stream)

    @classmethod
    async def open(cls, port: int, *, read: bool = True, version: int = 1, **kw: Any) -> Client:
        """``version=2`` offers ``posecast.v2`` (and decodes what it gets as v2)."""
        proto = SUBPROTOCOLS[version] if version != 1 else SUBPROTOCOL
        ws = await connect(f"ws://127.0.0.1:{port}/", subprotocols=[proto], **kw)  # type: ignore[list-item]
        return cls(ws, read, version)

    async def _read(self) -> None:
        try:
            async for data in self.ws:
                assert isinstance(data, bytes)
                self.messages.append(decode(data, version=self.version))
                self._new.set()
        except ConnectionClosed:
            pass
        finally:
            self.closed.set()
            self._new.set()

    async def send(self, msg: Message | bytes) -> None:
        await self.ws.send(msg if isinstance(msg, bytes) else encode(msg))

    async def hello(self, tok: str, room: str = "r1", name: str = "Ann", **kw: Any) -> Message:
        await self.send(Hello(self.version, tok, room, name, **kw))
        return await self.wait_for(lambda m: isinstance(m, Welcome | Error))

    async def wait_for(
        self, pred: Callable[[Message], bool], timeout: float = 5.0, start: int = 0
    ) -> Message:
        deadline = time.monotonic() + timeout
        i = start
        while True:
            while i < len(self.messages):
                if pred(self.messages[i]):
                    return self.messages[i]
                i += 1
            if self.closed.is_set():
                raise AssertionError(f"closed before a match; got {self.messages[-5:]}")
            left = deadline - time.monotonic()
            if left <= 0:
                raise AssertionError(f"no match in {timeout} s; last: {self.messages[-3:]}")
            self._new.clear()
            with contextlib.suppress(TimeoutError):
                await asyncio.wait_for(self._new.wait(), left)

    async def error(self, timeout: float = 5.0, start: int = 0) -> Error:
        m = await self.wait_for(lambda m: isinstance(m, Error), timeout, start)
        assert isinstance(m, Error)
        return m

    def poses(self, player: str | None = None) -> list[Pose]:
        return [m for m in self.messages if isinstance(m, Pose) and player in (None, m.player)]

    def stream(self, seed: int = 0, seq0: int = 0, hz: float = 60.0) -> None:
        """Start sending walk frames at ``hz`` in the background."""

        async def run() -> None:
            seq = seq0
            with contextlib.suppress(ConnectionClosed):
                while True:
                    self.sent_at[seq] = time.monotonic()
                    await self.send(walk_frame(seq, seed))
                    seq += 1
                    await asyncio.sleep(1 / hz)

        self._sender = asyncio.create_task(run())

    async def close(self) -> None:
        if self._sender is not None:
            self._sender.cancel()
        await self.ws.close()
        if self._reader is not None:
            await self._reader
