"""``posecast demo`` (what ``make run`` starts): the server with the shipped models, two
simulated headsets replaying motion at 60 Hz, and a spectator that reports what the
room receives. Alice wears a waist tracker (layout ``hmd3+waist``); Bob has only a
headset and two controllers (``hmd3``): one room, both models.

The headsets replay a BVH file when given one (``--bvh``), else a generated walk.
The printed ``viewer:`` URL opens the live 3D viewer on the room (the demo runs with
dev settings, so the page gets its spectator token from the server itself).
Everything runs on loopback in this process; Ctrl-C (or ``--seconds``) stops it.
"""

from __future__ import annotations

import asyncio
import contextlib
import secrets
import signal
import time
from dataclasses import replace
from pathlib import Path

import numpy as np
from websockets.asyncio.client import ClientConnection, connect
from websockets.exceptions import ConnectionClosed
from websockets.typing import Subprotocol

from posecast.offline.dataset.frames import Frames, derive_frames
from posecast.offline.motion.synthetic import walk_clip
from posecast.online.auth.tokens import mint
from posecast.online.config import ServerConfig
from posecast.online.protocol import decode, encode
from posecast.online.protocol.messages import (
    SUBPROTOCOL,
    Frame,
    Hello,
    Pose,
    Presence,
    Welcome,
)
from posecast.online.shell.app import PosecastServer
from posecast.skeleton import Joint
from posecast.tracking.features import TrackerSlot
from posecast.tracking.layouts import Layout


def motion(bvh: Path | None, seed: int) -> Frames:
    """Tracker frames to replay: a BVH clip, or a generated walk."""
    if bvh is None:
        return derive_frames(walk_clip(seconds=12.0, fps=60.0, seed=seed))
    from posecast.offline.dataset.prepare import process_file
    from posecast.offline.motion.rig import load_rigs

    return process_file(bvh, load_rigs())[1]


async def headset(
    url: str,
    token: str,
    name: str,
    frames: Frames,
    offset_m: float,
    layout: Layout = Layout.HMD3_WAIST,
) -> None:
    """Connect, join, and send frames at 60 Hz forever (looping the clip). A headset-only
    player (``layout="hmd3"``) sends no waist: that slot is zero and marked not valid."""
    waist = layout == Layout.HMD3_WAIST
    async with connect(url, subprotocols=[Subprotocol(SUBPROTOCOL)]) as ws:
        await ws.send(encode(Hello(1, token, "demo", name, None if waist else layout)))
        reply = await ws.recv()
        welcome = decode(reply if isinstance(reply, bytes) else reply.encode())
        if not isinstance(welcome, Welcome):
            raise RuntimeError(f"{name}: server refused: {welcome}")
        shift = np.array([offset_m, 0.0, 0.0])
        t0, seq = time.monotonic(), 0
        # A player receives every pose of its room: read (and drop) them, or the server
        # cuts this headset off as a SLOW_CONSUMER once the socket buffers fill (~30 s).
        drain = asyncio.create_task(_drain(ws))
        try:
            with contextlib.suppress(ConnectionClosed):
                while True:
                    i = seq % len(frames["features"])
                    pos = frames["tracker_pos"][i].astype(np.float64) + shift
                    quat = frames["tracker_quat"][i].astype(np.float64)
                    if not waist:
                        pos[TrackerSlot.WAIST], quat[TrackerSlot.WAIST] = 0.0, 0.0
                    t = time.monotonic() - t0
                    await ws.send(encode(Frame(seq, t, pos, quat, 0b1111 if waist else 0b0111)))
                    seq += 1
                    await asyncio.sleep(max(0.0, t0 + seq / 60.0 - time.monotonic()))
        finally:
            drain.cancel()


async def _drain(ws: ClientConnection) -> None:
    with contextlib.suppress(ConnectionClosed):
        async for _ in ws:
            pass


async def spectator(url: str, token: str, every_s: float = 2.0) -> None:
    """Print, every ``every_s``, how many poses per second each player's avatar gets."""
    async with connect(url, subprotocols=[Subprotocol(SUBPROTOCOL)]) as ws:
        await ws.send(encode(Hello(1, token, "demo", "spectator")))
        counts: dict[str, int] = {}
        heads: dict[str, np.ndarray] = {}
        last = time.monotonic()
        async for data in ws:
            assert isinstance(data, bytes)
            msg = decode(data)
            if isinstance(msg, Pose):
                counts[msg.player] = counts.get(msg.player, 0) + 1
                heads[msg.player] = msg.positions[Joint.HEAD]
            elif isinstance(msg, Presence):
                print(f"presence: {msg.event} {msg.player}", flush=True)
            now = time.monotonic()
            if now - last >= every_s:
                for player, n in sorted(counts.items()):
                    head = np.round(heads[player], 2)
                    print(
                        f"{player}: {n / (now - last):5.1f} poses/s, head at {head} m", flush=True
                    )
                counts.clear()
                last = now


async def run(port: int, seconds: float | None, bvh: Path | None, samples: int) -> None:
    secret = secrets.token_urlsafe(32)
    cfg = ServerConfig.from_sources({}, {"dev": True, "token_secret": secret, "port": port})
    cfg = replace(cfg, samples=samples)
    server = PosecastServer(cfg)
    await server.start()
    url = f"ws://127.0.0.1:{server.port}/"
    print(
        f"posecast demo: server on {url}  (health: http://127.0.0.1:{server.port}/healthz,"
        f" metrics: http://127.0.0.1:{server.port}/metrics)",
        flush=True,
    )
    print(f"viewer: http://127.0.0.1:{server.port}/viewer?room=demo", flush=True)
    now = time.time()

    def token(player: str, role: str = "player") -> str:
        return mint(secret.encode(), room="demo", player=player, role=role, ttl_s=3600, now=now)

    tasks = [
        asyncio.create_task(headset(url, token("alice"), "Alice", motion(bvh, 1), -0.8)),
        asyncio.create_task(headset(url, token("bob"), "Bob", motion(bvh, 2), 0.8, Layout.HMD3)),
        asyncio.create_task(spectator(url, token("viewer", "spectator"))),
    ]
    # SIGTERM (a process manager, `kill`, a container stop) ends the demo as Ctrl-C
    # does: the players leave and the server drains, exit 0 (it was killed, 143).
    stop = asyncio.Event()
    loop = asyncio.get_running_loop()
    with contextlib.suppress(NotImplementedError):  # an event loop without signals
        loop.add_signal_handler(signal.SIGTERM, stop.set)
    body = asyncio.ensure_future(
        asyncio.gather(*tasks) if seconds is None else asyncio.sleep(seconds)
    )
    stopping = asyncio.create_task(stop.wait())
    try:
        await asyncio.wait({body, stopping}, return_when=asyncio.FIRST_COMPLETED)
        if body.done():
            body.result()  # a failed headset or spectator fails the demo, as before
    finally:
        for t in (*tasks, body, stopping):
            t.cancel()
        await asyncio.gather(*tasks, body, stopping, return_exceptions=True)
        with contextlib.suppress(NotImplementedError):
            loop.remove_signal_handler(signal.SIGTERM)
        await server.stop()
