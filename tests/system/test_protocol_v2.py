"""Protocol v2 end to end: a real server, v1 and v2 clients in one room.

The v2 client rebuilds every avatar from the records (the server's reference
decoder, :mod:`posecast.online.protocol.records`) and FK with the announced
skeletons; a v1 client in the same room gets the plain ``pose`` messages, which are
the yardstick: same seq, positions within 1 cm, rotations within 0.5 degrees.
"""

from __future__ import annotations

import asyncio
import json
import subprocess
import sys
from collections.abc import Coroutine
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from posecast.geometry.rotations import quat_conj, quat_mul
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
REPO = Path(__file__).resolve().parents[2]


def run(coro: Coroutine[Any, Any, None]) -> None:
    asyncio.run(coro)


class Decoded:
    """What a v2 client holds: avatar ids, skeletons, references, and every pose rebuilt."""

    def __init__(self, welcome: Welcome) -> None:
        self.player_of: dict[int, str] = {}
        self.bones: dict[int, np.ndarray] = {}
        self.refs: dict[int, records.Recon | None] = {}
        self.poses: list[tuple[str, records.Record, np.ndarray]] = []
        self.messages = 0
        for m in welcome.members:
            assert m.avatar_id is not None and m.skeleton is not None
            self.announce(m.player, m.avatar_id, m.skeleton)

    def announce(self, player: str, avatar_id: int, skeleton: bytes) -> None:
        if self.player_of.get(avatar_id) != player:
            self.refs[avatar_id] = None
        self.player_of[avatar_id] = player
        self.bones[avatar_id] = records.bytes2skeleton(skeleton)

    def feed(self, msgs: list[Any]) -> None:
        for msg in msgs:
            if isinstance(msg, Presence) and msg.event == "join":
                assert msg.avatar_id is not None and msg.skeleton is not None
                self.announce(msg.player, msg.avatar_id, msg.skeleton)
            elif isinstance(msg, Skeleton):
                self.bones[msg.avatar_id] = records.bytes2skeleton(msg.skeleton)
            elif isinstance(msg, Poses):
                self.messages += 1
                for rec in records.decode_records(msg.data, self.refs):
                    pos = rec.recon.positions(self.bones[rec.avatar_id])
                    self.poses.append((self.player_of[rec.avatar_id], rec, pos))


def _angle_deg(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """The angle between rotations (robust near zero: v1's snorm16 quaternions are up to
    3e-5 off unit length, which arccos of their dot product would read as 0.9 deg)."""
    a = a / np.linalg.norm(a, axis=-1, keepdims=True)
    b = b / np.linalg.norm(b, axis=-1, keepdims=True)
    rel = quat_mul(quat_conj(a), b)
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
            assert matched > 30 and worst < 0.5, (matched, worst)
            assert {p for p, _, _ in got.poses} == {"a", "b"}
            # a's calibration reached the v2 client as a skeleton message, before its poses
            assert any(isinstance(m, Skeleton) and m.player == "a" for m in new.messages)
            # every record in one message per tick, keyframes at least every second
            counts = [m for m in new.messages if isinstance(m, Poses)]
            assert got.messages == len(counts) and len(got.poses) > 1.6 * len(counts)
            keys = [rec for p, rec, _ in got.poses if p == "b" and rec.keyframe]
            deltas = [rec for p, rec, _ in got.poses if p == "b" and not rec.keyframe]
            assert keys and len(deltas) > 10 * len(keys), (len(keys), len(deltas))
            # the 30 Hz spectator got about half as many poses
            assert 0.35 < len(half.poses) / len(got.poses) < 0.65
            assert server.metrics.value("posecast_errors_total", {"code": "BAD_FIELD"}) == 0

    run(scenario())


def test_pose_rate_changes_what_comes(engine_factory: Factory) -> None:
    """A v2 spectator at 60 Hz, then 15 Hz, against a v1 spectator's count of ticks
    (one pose per tick): about 1 pose a tick, then about 1 in 4. Counting against the
    v1 stream, not the clock, keeps this true on a machine too slow for 60 ticks a
    second."""

    async def scenario() -> None:
        async with serving(make_cfg(lookahead=2), engine_factory) as server:
            a = await Client.open(server.port)
            ref = await Client.open(server.port)
            c = await Client.open(server.port, version=2)
            assert isinstance(await a.hello(token("r1", "a")), Welcome)
            assert isinstance(await ref.hello(token("r1", "r", role="spectator")), Welcome)
            w = await c.hello(token("r1", "c", role="spectator"))
            assert isinstance(w, Welcome)
            a.stream(seed=3)
            await c.wait_for(lambda m: isinstance(m, Poses))
            await asyncio.sleep(1.0)
            marks = [(len(ref.poses()), len(c.messages))]
            await c.send(PoseRate(15.0))
            await asyncio.sleep(0.3)  # the change is in effect by now
            marks.append((len(ref.poses()), len(c.messages)))
            await asyncio.sleep(1.5)
            marks.append((len(ref.poses()), len(c.messages)))
            for cl in (a, ref, c):
                await cl.close()
            d = Decoded(w)

            def got(lo: int, hi: int) -> int:
                before = len(d.poses)
                d.feed(c.messages[lo:hi])
                return len(d.poses) - before

            fast = got(0, marks[0][1]) / max(1, marks[0][0])
            got(marks[0][1], marks[1][1])
            slow = got(marks[1][1], marks[2][1]) / max(1, marks[2][0] - marks[1][0])
            assert fast > 0.8 and 0.15 < slow < 0.35, (fast, slow)

    run(scenario())


@pytest.mark.timeout(300)
def test_an_8_player_room_gets_at_most_64_bytes_a_pose(tmp_path: Path) -> None:
    """``benchmarks/bandwidth.py`` (the server's core and engine in simulated time, the
    SDK decoding): an 8-player room at 60 Hz of the SDK's procedural walks, v2 within
    64 bytes a pose (v1: 347), every rebuilt pose within 1 cm and 0.5 degrees."""
    out = tmp_path / "bw.json"
    cmd = [sys.executable, str(REPO / "benchmarks" / "bandwidth.py"), "--rooms", "8",
           "--seconds", "2", "--samples", "8", "--walk", "--json", str(out)]  # fmt: skip
    subprocess.run(cmd, check=True, cwd=REPO, capture_output=True, timeout=280)
    (room,) = json.loads(out.read_text())["rooms"]
    assert room["v2_60"]["poses_per_s"] == room["v1_60"]["poses_per_s"] == 480.0
    assert room["v2_60"]["bytes_per_pose"] <= 64.0, room
    assert 340 < room["v1_60"]["bytes_per_pose"] < 350
    assert room["v2_20"]["poses_per_s"] == 160.0
    assert room["v2_compared_poses"] > 500
    assert room["v2_max_position_error_m"] < 0.01 and room["v2_max_rotation_error_deg"] < 0.5
