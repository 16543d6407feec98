"""A TCP proxy between a node and Redis, for the faults a stopped process cannot
make: latency on every round trip, and a connection that goes silent without closing
(a half-open TCP connection, a NAT or firewall that forgot it).

It runs its own event loop on a thread, so a test's blocking calls never stall it.
A connection that sends ``SUBSCRIBE`` is the node's pub/sub connection; the others
carry its commands.
"""

from __future__ import annotations

import asyncio
import contextlib
import threading
import time
from collections.abc import Coroutine
from typing import Any, TypeVar

T = TypeVar("T")


class _Link:
    """One client connection and its connection to Redis."""

    def __init__(self, writers: tuple[asyncio.StreamWriter, asyncio.StreamWriter]) -> None:
        self.writers = writers
        self.pubsub = False
        self.frozen = False
        self.tasks: list[asyncio.Task[None]] = []

    def close(self) -> None:
        for task in self.tasks:
            task.cancel()
        for w in self.writers:
            w.close()


class RedisProxy:
    """Forwards 127.0.0.1:``port`` to Redis on ``target_port``; every chunk waits
    ``delay_s`` (each way) before it is passed on."""

    def __init__(self, target_port: int) -> None:
        self.target_port = target_port
        self.delay_s = 0.0
        self._links: list[_Link] = []
        self._loop = asyncio.new_event_loop()
        self._thread = threading.Thread(target=self._loop.run_forever, daemon=True)
        self._thread.start()
        self._server = self._call(asyncio.start_server(self._accept, "127.0.0.1", 0))
        self.port: int = self._server.sockets[0].getsockname()[1]

    @property
    def url(self) -> str:
        return f"redis://127.0.0.1:{self.port}/0"

    def freeze(self, *, pubsub: bool) -> int:
        """Stop passing anything on the open pub/sub (or command) connections, both
        ways, without closing them; how many."""
        return self._call(self._mark(pubsub, freeze=True))

    def drop(self, *, pubsub: bool) -> int:
        """Close the open pub/sub (or command) connections; how many."""
        return self._call(self._mark(pubsub, freeze=False))

    def close(self) -> None:
        async def shut() -> None:
            self._server.close()
            for link in self._links:
                link.close()
            tasks = [t for link in self._links for t in link.tasks]
            await asyncio.gather(*tasks, return_exceptions=True)
            closing = [w.wait_closed() for link in self._links for w in link.writers]
            await asyncio.gather(*closing, return_exceptions=True)
            await self._server.wait_closed()

        with contextlib.suppress(Exception):
            self._call(shut())
        self._loop.call_soon_threadsafe(self._loop.stop)
        self._thread.join(10)
        self._loop.close()

    # --- on the proxy's own loop -------------------------------------------------------

    def _call(self, coro: Coroutine[Any, Any, T]) -> T:
        return asyncio.run_coroutine_threadsafe(coro, self._loop).result(10)

    async def _mark(self, pubsub: bool, *, freeze: bool) -> int:
        found = [x for x in self._links if x.pubsub == pubsub and not x.writers[0].is_closing()]
        for link in found:
            if freeze:
                link.frozen = True
            else:
                link.close()
        return len(found)

    async def _accept(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        try:
            up_reader, up_writer = await asyncio.open_connection("127.0.0.1", self.target_port)
        except OSError:
            writer.close()
            return
        link = _Link((writer, up_writer))
        self._links.append(link)
        link.tasks = [
            asyncio.create_task(self._pump(link, reader, up_writer, upstream=True)),
            asyncio.create_task(self._pump(link, up_reader, writer, upstream=False)),
        ]

    async def _pump(
        self,
        link: _Link,
        reader: asyncio.StreamReader,
        writer: asyncio.StreamWriter,
        *,
        upstream: bool,
    ) -> None:
        """Read as it comes; write each chunk ``delay_s`` after it came (in order)."""
        queue: asyncio.Queue[tuple[float, bytes]] = asyncio.Queue()

        async def send() -> None:
            while True:
                arrived, data = await queue.get()
                if not data:
                    break
                wait = arrived + self.delay_s - time.monotonic()
                if wait > 0:
                    await asyncio.sleep(wait)
                while link.frozen:
                    await asyncio.sleep(0.05)
                writer.write(data)
                await writer.drain()
            writer.close()

        sender = asyncio.create_task(send())
        try:
            while data := await reader.read(65536):
                if upstream and b"SUBSCRIBE" in data.upper():
                    link.pubsub = True
                queue.put_nowait((time.monotonic(), data))
            queue.put_nowait((0.0, b""))
            await sender
        except (OSError, asyncio.CancelledError):
            pass
        finally:
            sender.cancel()
            with contextlib.suppress(BaseException):
                await sender
