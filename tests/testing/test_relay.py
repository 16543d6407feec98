"""The lossy relay's downlink jitter (posecast.testing.relay): messages held, never
reordered. Its uplink faults are exercised by the reliability suite
(``tests/system/reliability/test_fault_network.py``)."""

from __future__ import annotations

import asyncio
import time

from websockets.asyncio.client import connect
from websockets.asyncio.server import ServerConnection, serve

from posecast.online.protocol.messages import SUBPROTOCOL_V2
from posecast.testing.relay import LossyRelay


def test_downlink_jitter_holds_messages_in_order() -> None:
    async def upstream(ws: ServerConnection) -> None:
        for i in range(40):  # as a server sends: one message every 5 ms
            await ws.send(i.to_bytes(2, "big") + time.monotonic().hex().encode())
            await asyncio.sleep(0.005)
        await ws.wait_closed()

    async def scenario() -> list[tuple[int, float]]:
        async with serve(upstream, "127.0.0.1", 0, subprotocols=[SUBPROTOCOL_V2]) as server:
            port = server.sockets[0].getsockname()[1]
            relay = LossyRelay(f"ws://127.0.0.1:{port}/", drop=0.0, jitter_s=0.0, seed=3,
                               protocols=(SUBPROTOCOL_V2,), down_jitter_s=0.03)  # fmt: skip
            await relay.start()
            got = []
            async with connect(relay.url, subprotocols=[SUBPROTOCOL_V2]) as ws:
                assert ws.subprotocol == SUBPROTOCOL_V2  # the client's choice, upstream too
                for _ in range(40):
                    data = await ws.recv()
                    assert isinstance(data, bytes)
                    sent = float.fromhex(data[2:].decode())
                    got.append((int.from_bytes(data[:2], "big"), time.monotonic() - sent))
            await relay.stop()
            return got

    got = asyncio.run(scenario())
    assert [i for i, _ in got] == list(range(40))  # in order, none lost
    held = [d for _, d in got]
    assert max(held) > 0.01  # held: up to 30 ms each (in order, so later ones queue)
