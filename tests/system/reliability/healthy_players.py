"""The healthy players of the hostile-input tests, in a process of their own.

``python -m tests.system.reliability.healthy_players PORT`` joins :data:`HEALTHY` (two
rooms, two players each), streams walk frames at 60 Hz on a fixed schedule (frame
``k`` leaves at ``t0 + k / 60``, so a late wake-up does not lower the rate), and
prints one JSON line ``{"ready": true}`` once every watched receiver has seen its
partner's poses. Then each line on stdin is answered with one JSON line: the time
(``time.monotonic()``, the same clock in every process on Linux), the poses each
watched receiver got of its partner so far, every error each player got, the
players whose connection closed, and whose poses each player received.

Being a separate process, the attacker's CPU (hypothesis, the fuzzer's socket work)
and the server's are not charged to these players, and theirs not to the server:
their pose rate measures what the server delivered.
"""

from __future__ import annotations

import asyncio
import contextlib
import json
import sys
import time

from websockets.exceptions import ConnectionClosed

from posecast.online.protocol.messages import Error, Pose, Welcome
from tests.online.conftest import token, walk_frame
from tests.online.wsclient import Client

HEALTHY = {"r1": ("h1", "h2"), "r2": ("h3", "h4")}
# Receiver <- sender pairs whose pose rate is measured: in the attacked room and not.
WATCHED = (("h2", "h1"), ("h1", "h2"), ("h4", "h3"))
RATE_HZ = 60.0


async def _stream(client: Client, seed: int) -> None:
    """Frame ``k`` at ``t0 + k / RATE_HZ``; after a stall of this process, the missed
    frames follow at twice the rate (what the server's frame bucket allows without
    RATE_LIMITED: ``max_rate_hz`` 120) until the schedule is met again."""
    t0, seq = time.monotonic(), 0
    with contextlib.suppress(ConnectionClosed):
        while True:
            await client.send(walk_frame(seq, seed))
            seq += 1
            now = time.monotonic()
            await asyncio.sleep(max(t0 + seq / RATE_HZ - now, 0.5 / RATE_HZ))


def report(clients: dict[str, Client]) -> dict[str, object]:
    counts = {
        f"{r}<-{s}": sum(1 for m in clients[r].messages if isinstance(m, Pose) and m.player == s)
        for r, s in WATCHED
    }
    errors = {p: [m.code for m in c.messages if isinstance(m, Error)] for p, c in clients.items()}
    closed = [p for p, c in clients.items() if c.closed.is_set()]
    senders = {
        p: sorted({m.player for m in c.messages if isinstance(m, Pose)}) for p, c in clients.items()
    }
    return {
        "t": time.monotonic(),
        "counts": counts,
        "errors": errors,
        "closed": closed,
        "senders": senders,
    }


async def main(port: int) -> None:
    clients: dict[str, Client] = {}
    for room, players in HEALTHY.items():
        for player in players:
            client = await Client.open(port)
            welcome = await client.hello(token(room, player), room=room, name=player)
            assert isinstance(welcome, Welcome), welcome
            clients[player] = client
    tasks = [asyncio.create_task(_stream(c, seed)) for seed, c in enumerate(clients.values())]
    for receiver, sender in WATCHED:
        await clients[receiver].wait_for(
            lambda m, s=sender: isinstance(m, Pose) and m.player == s, timeout=20
        )
    print(json.dumps({"ready": True}), flush=True)
    loop = asyncio.get_running_loop()
    while await loop.run_in_executor(None, sys.stdin.readline):
        print(json.dumps(report(clients)), flush=True)
    for task in tasks:
        task.cancel()
    for client in clients.values():
        await client.close()


if __name__ == "__main__":
    asyncio.run(main(int(sys.argv[1])))
