"""Protocol v2 end to end: a real server, v1 and v2 clients in one room.

The v2 client rebuilds every avatar from the records (the server's reference
decoder, :mod:`posecast.online.protocol.records`) and FK with the announced
skeletons; a v1 client in the same room gets the plain ``pose`` messages, which are
the yardstick: same seq, positions within 1 cm, rotations within 0.5 degrees.
"""

from __future__ import annotations

import asyncio
from collections.abc import Coroutine
from typing import Any

import numpy as np
import pytest

from posecast.online.protocol import records
from posecast.online.protocol.messages import (
    Calibrate,
    Pose,
    PoseRate,
    Poses,
    Presence,
    Resync,
    Skeleton,
    Welcome,
)
from tests.online.conftest import make_cfg, token
from tests.online.wsclient import Client, Factory, serving

pytestmark = pytest.mark.timeout(40)


def run(coro: Coroutine[Any, Any, None]) -> None:
    asyncio.run(coro)


class Decoded:
    """What a v2 client holds: handles, skeletons, references, and every pose rebuilt."""

    def __init__(self, welcome: Welcome) -> None:
        self.player_of: dict[int, str] = {}
        self.bones: dict[int, np.ndarray] = {}
        self.refs: dict[int, records.Recon | None] = {}
        self.poses: list[tuple[str, records.Record, np.ndarray]] = []
        self.messages = 0
        for m in welcome.members:
            assert m.handle is not None and m.skeleton is not None
            self.announce(m.player, m.handle, m.skeleton)

    def announce(self, player: str, handle: int, skeleton: bytes) -> None:
        if self.player_of.get(handle) != player:
            self.refs[handle] = None
        self.player_of[handle] = player
        self.bones[handle] = records.bytes2skeleton(skeleton)

    def feed(self, msgs: list[Any]) -> None:
        for msg in msgs:
            if isinstance(msg, Presence) and msg.event == "join":
                assert msg.handle is not None and msg.skeleton is not None
                self.announce(msg.player, msg.handle, msg.skeleton)
            elif isinstance(msg, Skeleton):
                self.bones[msg.handle] = records.bytes2skeleton(msg.skeleton)
            elif isinstance(msg, Poses):
                self.messages += 1
                for rec in records.decode_records(msg.data, self.refs):
                    pos = rec.recon.positions(self.bones[rec.handle])
                    self.poses.append((self.player_of[rec.handle], rec, pos))


def _angle_deg(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """The angle between rotations (robust near zero: v1's snorm16 quaternions are up to
    3e-5 off unit length, which arccos of their dot product would read as 0.9 deg)."""
    a = a / np.linalg.norm(a, axis=-1, keepdims=True)
    b = b / np.linalg.norm(b, axis=-1, keepdims=True)
    rel = records._qmul(records._conj(a), b)
    out: np.ndarray = np.degrees(np.linalg.norm(records.quat2rotvec(rel), axis=-1))
    return out


def test_v1_and_v2_clients_share_a_room(engine_factory: Factory) -> None:
    async def scenario() -> None:
        async with serving(make_cfg(lookahead=2), engine_factory) as server:
            old = await Client.open(server.port)  # a v1 client, unchanged
            new = await Client.open(server.port, version=2)
            slow = await Client.open(server.port, version=2)
            assert new.ws.subprotocol == "posecast.v2" and old.ws.subprotocol == "posecast.v1"
            assert isinstance(await old.hello(token("r1", "a")), Welcome)
            w = await new.hello(token("r1", "b"), name="Bea")
            assert isinstance(w, Welcome) and w.version == 2 and w.pose_rate_hz == 60.0
            ws = await slow.hello(token("r1", "s", role="spectator"), pose_rate_hz=30.0)
            assert isinstance(ws, Welcome) and ws.pose_rate_hz == 30.0
            old.stream(seed=1)
            new.stream(seed=2)
            await old.send(Calibrate(height_m=1.9))
            await old.wait_for(lambda m: isinstance(m, Pose) and m.player == "b")
            await asyncio.sleep(1.5)
            await new.send(Resync())
            await asyncio.sleep(0.3)
            for c in (old, new, slow):
                await c.close()
            got, half = Decoded(w), Decoded(ws)
            got.feed(new.messages)
            half.feed(slow.messages)
            assert not [m for m in new.messages if isinstance(m, Pose)]  # v2: poses only

            truth = {(p.player, p.seq): p for p in old.poses()}
            matched, worst = 0, 0.0
            for player, rec, pos in got.poses:
                ref = truth.get((player, rec.recon.seq))
                if ref is None or ref.rotations is None:
                    continue
                matched += 1
                assert np.abs(pos - ref.positions).max() < 0.01, player
                world = records.items2world(rec.recon.items)
                worst = max(worst, float(_angle_deg(world, ref.rotations).max()))
            assert matched > 100 and worst < 0.5, (matched, worst)
            assert {p for p, _, _ in got.poses} == {"a", "b"}
            # a's calibration reached the v2 client as a skeleton message, before its poses
            assert any(isinstance(m, Skeleton) and m.player == "a" for m in new.messages)
            # every record in one message per tick, keyframes at least every second
            counts = [m for m in new.messages if isinstance(m, Poses)]
            assert got.messages == len(counts) and len(got.poses) > 1.6 * len(counts)
            keys = [rec for p, rec, _ in got.poses if p == "b" and rec.keyframe]
            assert 2 <= len(keys) <= 6, len(keys)
            # the 30 Hz spectator got about half as many poses
            assert 0.35 < len(half.poses) / len(got.poses) < 0.65
            assert server.metrics.value("posecast_errors_total", {"code": "BAD_FIELD"}) == 0

    run(scenario())


def test_pose_rate_and_resync_change_what_comes(engine_factory: Factory) -> None:
    async def scenario() -> None:
        async with serving(make_cfg(lookahead=2), engine_factory) as server:
            c = await Client.open(server.port, version=2)
            w = await c.hello(token("r1", "a"))
            assert isinstance(w, Welcome)
            c.stream(seed=3)
            await c.wait_for(lambda m: isinstance(m, Poses))
            await asyncio.sleep(0.5)
            start = len(c.messages)
            await c.send(PoseRate(15.0))
            await asyncio.sleep(1.2)
            mid = len(c.messages)
            await c.send(Resync())
            await asyncio.sleep(0.4)
            await c.close()
            d = Decoded(w)
            d.feed(c.messages[:mid])
            ts = [m.t for m in c.messages[:mid] if isinstance(m, Poses)]
            gaps = np.diff(ts)
            fast, slow = np.median(gaps[:10]), np.median(gaps[-8:])  # 60 Hz, then 15 Hz
            assert fast < 1.5 / 60 and 3.5 / 60 < slow < 4.5 / 60, (fast, slow)
            assert start < mid
            # soon after the resync, one message of keyframes only (ticks are 4 apart)
            later = [m for m in c.messages[mid:] if isinstance(m, Poses)][:3]
            keyed = []
            for msg in later:
                recs = records.decode_records(msg.data, d.refs)
                keyed.append(all(r.keyframe for r in recs))
            assert any(keyed), keyed

    run(scenario())
