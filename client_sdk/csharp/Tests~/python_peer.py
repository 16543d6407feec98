"""A Python SDK client for the C# end-to-end test: joins a room, streams a walk, and
prints (one JSON line) the poses it received of the player named on the command line.

    python python_peer.py URL SECRET ROOM WATCH_PLAYER SECONDS
"""

from __future__ import annotations

import asyncio
import json
import sys

import posecast_client as pc


async def main(url: str, secret: str, room: str, watch: str, seconds: float) -> None:
    token = pc.mint_token(secret, room=room, player="py-peer")
    seen: dict[int, list[list[float]]] = {}
    players: set[str] = set()
    async with pc.connect(url, token, reconnect=False) as client:
        await client.join(room, "Python peer")
        streaming = asyncio.create_task(client.stream(pc.WalkSource(seconds=seconds)))
        async for event in client.events(until=streaming):
            if isinstance(event, pc.Pose):
                players.add(event.player)
                if event.player == watch:
                    seen[event.seq] = [[float(v) for v in p] for p in event.positions]
    print(json.dumps({"players": sorted(players), "poses": seen}))


if __name__ == "__main__":
    asyncio.run(main(sys.argv[1], sys.argv[2], sys.argv[3], sys.argv[4], float(sys.argv[5])))
