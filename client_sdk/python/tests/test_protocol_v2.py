"""Protocol v2 through the SDK against a real ``posecast serve --dev``.

A v2 client (the default) and a v1 client (``protocol=1``) watch the same player:
the v1 poses carry the server's positions and world rotations as sent, the v2 ones
are rebuilt by this SDK from records and skeletons. Same seq: positions within
1 cm, world rotations within 0.5 degrees; v2 poses are a fraction of the bytes.
Also ``posecast-sim``'s ``bytes_per_pose``, and the fallback to a v1-only server.
"""

from __future__ import annotations

import asyncio
import json
from collections.abc import Coroutine
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from websockets.asyncio.server import serve
from websockets.typing import Subprotocol

import posecast_client as pc
from posecast_client.cli import sim
from posecast_client.codec import decode, encode
from sdk_helpers import DevServer, EventLog, for_seconds

DATA = Path(__file__).parent / "data"


def run(coro: Coroutine[Any, Any, None], timeout_s: float = 40.0) -> None:
    asyncio.run(asyncio.wait_for(coro, timeout_s))


def _angle_deg(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Angles between rotations, robust for the v1 snorm16 ones (up to 3e-5 off unit)."""
    a = a / np.linalg.norm(a, axis=-1, keepdims=True)
    b = b / np.linalg.norm(b, axis=-1, keepdims=True)
    dot = np.abs(np.einsum("...i,...i->...", a, b))
    cross = np.linalg.norm(a[..., 3:] * b[..., :3] - b[..., 3:] * a[..., :3]
                           + np.cross(a[..., :3], b[..., :3]), axis=-1)  # fmt: skip
    out: np.ndarray = np.degrees(2.0 * np.arctan2(cross, dot))
    return out


def test_v2_poses_match_the_v1_ones_within_the_bounds(dev_server: DevServer, uid: str) -> None:
    room = f"v2-{uid}"

    async def main() -> None:
        ada = await pc.connect(dev_server.url, dev_server.token(room, f"ada-{uid}"))
        new = await pc.connect(dev_server.url, dev_server.token(room, f"new-{uid}"))
        old = await pc.connect(dev_server.url, dev_server.token(room, f"old-{uid}"), protocol=1)
        async with ada, new, old:
            await ada.join(room, "Ada")
            await ada.calibrate(height_m=1.62)  # a short user: the skeleton changes
            w_new, w_old = await new.join(room, "New"), await old.join(room, "Old")
            assert (new.version, old.version, w_new.version, w_old.version) == (2, 1, 2, 1)
            assert all(m.avatar_id is not None and m.skeleton is not None for m in w_new.members)
            logs = EventLog(new), EventLog(old)
            source = pc.BvhReplaySource(DATA / "walk_cmu_mb.bvh", loop=True)
            streaming = asyncio.create_task(ada.stream(for_seconds(source, 3.0)))
            await streaming
            await asyncio.sleep(0.3)
            for log in logs:
                log.stop()
            v2 = {p.seq: p for p in logs[0].events if isinstance(p, pc.Pose)}
            v1 = {p.seq: p for p in logs[1].events if isinstance(p, pc.Pose)}
            both = sorted(set(v1) & set(v2))
            assert len(both) > 30
            pos_err = max(float(np.abs(v2[s].positions - v1[s].positions).max()) for s in both)
            rot_err = max(float(_angle_deg(v2[s].rotations, v1[s].rotations).max()) for s in both)
            assert pos_err < 0.01 and rot_err < 0.5, (pos_err, rot_err)
            p = v2[both[-1]]
            assert p.local_rotations is not None and p.local_rotations.shape == (19, 4)
            assert any(v2[s].keyframe for s in both) and not all(v2[s].keyframe for s in both)
            bytes_v2 = new.stats.pose_bytes / max(1, new.stats.poses)
            bytes_v1 = old.stats.pose_bytes / max(1, old.stats.poses)
            assert bytes_v2 < 0.4 * bytes_v1, (bytes_v2, bytes_v1)
            assert new.stats.bad_records == 0

    run(main())


def test_sim_reports_bytes_per_pose(
    dev_server: DevServer, capsys: pytest.CaptureFixture[str], tmp_path: Path, uid: str
) -> None:
    out = tmp_path / "sim.json"
    args = ["--url", dev_server.url, "--secret", dev_server.secret, "--players", "3",
            "--duration", "3", "--bvh", str(DATA / "walk_cmu_mb.bvh"), "-q"]  # fmt: skip
    assert sim.main([*args, "--room-prefix", f"b2-{uid}", "--json", str(out)]) == 0
    v2 = json.loads(out.read_text())
    assert (
        sim.main([*args, "--room-prefix", f"b1-{uid}", "--json", str(out), "--protocol", "1"]) == 0
    )
    v1 = json.loads(out.read_text())
    assert "bytes per pose" in capsys.readouterr().out
    assert v2["protocol"] == [2] and v1["protocol"] == [1]
    # 3 players a room: a v2 message per tick holds up to 3 poses (fewer on a machine
    # too busy for the sim to keep up, whose superseded poses also make longer deltas;
    # the 64-byte bound of an 8-player room is tests/system/test_protocol_v2.py's, in
    # simulated time); v1 sends 347-byte poses
    assert 330 < v1["bytes_per_pose"] < 360, v1
    assert 30 < v2["bytes_per_pose"] < 0.4 * v1["bytes_per_pose"], (v2, v1)


def test_falls_back_to_v1_when_the_server_only_speaks_it() -> None:
    async def main() -> None:
        seen: list[str | None] = []

        async def handler(ws: Any) -> None:
            seen.append(ws.subprotocol)
            hello = decode(await ws.recv())
            assert isinstance(hello, pc.Hello) and hello.version == 1
            welcome = pc.Welcome(1, "p", "s", "player", "r", 1.0, 60.0, 10,
                                 (pc.Member("p", "P"),), pc.Limits())  # fmt: skip
            await ws.send(encode(welcome))
            await asyncio.sleep(0.2)

        async with serve(handler, "127.0.0.1", 0, subprotocols=[Subprotocol("posecast.v1")]) as srv:
            port = srv.sockets[0].getsockname()[1]
            client = await pc.connect(f"ws://127.0.0.1:{port}/", "tok", reconnect=False)
            async with client:
                w = await client.join("r", "P", pose_rate_hz=30.0)
                assert w.version == 1 and client.version == 1
                with pytest.raises(ValueError):
                    await client.set_pose_rate(30.0)
        assert seen == ["posecast.v1"]

    run(main())
