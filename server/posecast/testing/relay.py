"""A lossy, jittery WebSocket relay between clients and a posecast server, for the
reliability suite (``tests/system/reliability``) and ``posecast bench latency``.

Client-to-server ``frame`` messages are dropped with probability ``drop``; every
client-to-server message is held for a random ``0..jitter_s`` (independently, so
frames overtake each other). Server-to-client traffic passes untouched, unless
``down_jitter_s`` holds each message a random ``0..down_jitter_s`` too, in order (as
TCP delivers a stream whose packets were delayed: none overtakes another, and a v2
client's delta records stay applicable). Seeded: the same seed, the same faults.

TCP itself never loses a byte, so loss is applied to whole messages, as a link that
loses packets would look to the application after its retransmit gives up.
"""

from __future__ import annotations

import asyncio
import contextlib
import random
from collections.abc import Sequence
from dataclasses import dataclass, field

from websockets.asyncio.client import connect as ws_connect
from websockets.asyncio.server import Server, ServerConnection, serve
from websockets.exceptions import ConnectionClosed
from websockets.typing import Subprotocol

from posecast.online.protocol import decode
from posecast.online.protocol.messages import SUBPROTOCOL, SUBPROTOCOLS, Frame


@dataclass
class RelayStats:
    frames_in: int = 0
    frames_dropped: int = 0
    frames_reordered: int = 0  # forwarded after a frame with a higher seq
    other_in: int = 0
    delays_s: list[float] = field(default_factory=list)


class LossyRelay:
    """A WebSocket relay between clients and ``upstream`` (see the module docstring).

    Args:
        upstream: the server's WebSocket URL.
        drop: the probability that a client's ``frame`` is dropped.
        jitter_s: every client-to-server message is held ``uniform(0, jitter_s)``.
        seed: seeds the drops and the delays.
        protocols: the subprotocols offered to clients, preferred first (``posecast.v1``
            only by default); the relay speaks to ``upstream`` the one its client chose.
        down_jitter_s: every server-to-client message is held ``uniform(0, this)``,
            in order (0: none).
    """

    def __init__(
        self,
        upstream: str,
        *,
        drop: float,
        jitter_s: float,
        seed: int,
        protocols: Sequence[str] = (SUBPROTOCOL,),
        down_jitter_s: float = 0.0,
    ) -> None:
        self.upstream, self.drop, self.jitter_s = upstream, drop, jitter_s
        self.down_jitter_s = down_jitter_s
        self.protocols = tuple(Subprotocol(p) for p in protocols)
        self.rng = random.Random(seed)
        self.stats = RelayStats()
        self._server: Server | None = None
        self.port = 0

    @property
    def url(self) -> str:
        return f"ws://127.0.0.1:{self.port}/"

    async def start(self) -> None:
        self._server = await serve(
            self._relay, "127.0.0.1", 0, subprotocols=list(self.protocols),
            compression=None, ping_interval=None,
        )  # fmt: skip
        self.port = self._server.sockets[0].getsockname()[1]

    async def stop(self) -> None:
        if self._server is not None:
            self._server.close()
            await self._server.wait_closed()

    async def _relay(self, down: ServerConnection) -> None:
        chosen = down.subprotocol or self.protocols[0]
        version = next(v for v, p in SUBPROTOCOLS.items() if p == chosen)
        async with ws_connect(
            self.upstream, subprotocols=[chosen], compression=None, ping_interval=None,
        ) as up:  # fmt: skip
            pending: set[asyncio.Task[None]] = set()
            last_seq = [-1]

            async def later(data: bytes, delay: float, seq: int | None) -> None:
                await asyncio.sleep(delay)
                if seq is not None:
                    if seq < last_seq[0]:
                        self.stats.frames_reordered += 1
                    last_seq[0] = max(last_seq[0], seq)
                with contextlib.suppress(ConnectionClosed):
                    await up.send(data)

            async def client_to_server() -> None:
                async for data in down:
                    assert isinstance(data, bytes)
                    msg = decode(data, version=version)
                    seq = msg.seq if isinstance(msg, Frame) else None
                    if seq is not None:
                        self.stats.frames_in += 1
                        if self.rng.random() < self.drop:
                            self.stats.frames_dropped += 1
                            continue
                    else:
                        self.stats.other_in += 1
                    delay = self.rng.uniform(0.0, self.jitter_s)
                    self.stats.delays_s.append(delay)
                    task = asyncio.create_task(later(data, delay, seq))
                    pending.add(task)
                    task.add_done_callback(pending.discard)

            async def server_to_client() -> None:
                if not self.down_jitter_s:
                    async for data in up:
                        await down.send(data)
                    return
                loop = asyncio.get_running_loop()
                held: asyncio.Queue[tuple[float, str | bytes]] = asyncio.Queue()
                sender = asyncio.create_task(send_held(held))
                release = 0.0
                try:
                    async for data in up:  # each after the one before it: in order
                        release = max(
                            release, loop.time() + self.rng.uniform(0.0, self.down_jitter_s)
                        )
                        held.put_nowait((release, data))
                finally:
                    sender.cancel()

            async def send_held(held: asyncio.Queue[tuple[float, str | bytes]]) -> None:
                loop = asyncio.get_running_loop()
                while True:
                    release, data = await held.get()
                    await asyncio.sleep(max(0.0, release - loop.time()))
                    with contextlib.suppress(ConnectionClosed):
                        await down.send(data)

            tasks = [
                asyncio.create_task(client_to_server()),
                asyncio.create_task(server_to_client()),
            ]
            with contextlib.suppress(ConnectionClosed):
                await asyncio.wait(tasks, return_when=asyncio.FIRST_COMPLETED)
            for t in (*tasks, *pending):
                t.cancel()
            await asyncio.gather(*tasks, *pending, return_exceptions=True)
