"""End to end: a headset-only (``hmd3``) player and a 4-point player in one room, on a
real server serving both shipped models (one engine batch per model)."""

from __future__ import annotations

import asyncio
import contextlib
from collections.abc import Callable

import numpy as np
import pytest
from websockets.exceptions import ConnectionClosed

from posecast.online.config import ServerConfig
from posecast.online.engine.multi import MultiEngine
from posecast.online.inference.loader import load_engine
from posecast.online.protocol.messages import Error, Frame, Welcome
from posecast.skeleton import Joint
from posecast.tracking.features import TrackerSlot
from tests.online.conftest import make_cfg, token, walk_frame
from tests.online.wsclient import Client, serving

pytestmark = pytest.mark.timeout(60)
BOTH = "hmd3+waist,hmd3"


def _factory(cfg: ServerConfig) -> Callable[[], MultiEngine]:
    ecfg = cfg.engine_config()
    engines = {
        layout: load_engine(ecfg, layout=layout, backend="onnx")
        for layout in ("hmd3+waist", "hmd3")
    }
    return lambda: MultiEngine(engines)


def _headset_only(seq: int, seed: int) -> Frame:
    """A walk frame as a headset without a waist tracker sends it: slot 3 not valid
    (and zeros, which a valid slot could not be)."""
    f = walk_frame(seq, seed)
    pos, quat = f.pos.copy(), f.quat.copy()
    pos[TrackerSlot.WAIST], quat[TrackerSlot.WAIST] = 0.0, 0.0
    return Frame(f.seq, f.t, pos, quat, valid=0b0111)


def test_a_headset_only_and_a_four_point_player_see_each_other() -> None:
    async def scenario() -> None:
        cfg = make_cfg(lookahead=2, layouts=BOTH)
        async with serving(cfg, _factory) as server:
            three, four = await Client.open(server.port), await Client.open(server.port)
            assert isinstance(await three.hello(token("r1", "q"), layout="hmd3"), Welcome)
            assert isinstance(await four.hello(token("r1", "w")), Welcome)

            async def send_hmd3() -> None:
                seq = 0
                with contextlib.suppress(ConnectionClosed):
                    while True:
                        await three.send(_headset_only(seq, seed=1))
                        seq += 1
                        await asyncio.sleep(1 / 60)

            task = asyncio.create_task(send_hmd3())
            four.stream(seed=2)
            # Wait for the poses themselves (how long 30 take depends on the machine's load).
            await four.wait_for(lambda m: len(four.poses("q")) >= 30, timeout=20.0)
            await three.wait_for(lambda m: len(three.poses("w")) >= 30, timeout=20.0)
            task.cancel()
            seen_by_four, seen_by_three = four.poses("q"), three.poses("w")
            assert len(seen_by_four) >= 30 and len(seen_by_three) >= 30
            assert not [m for m in three.messages + four.messages if isinstance(m, Error)]
            # The headset-only avatar stands where its headset is: the pose's head near
            # the tracked head, the pelvis (predicted, no waist tracker) under it.
            for p in seen_by_four[-20:]:
                head = walk_frame(p.seq, 1).pos[TrackerSlot.HEAD]
                assert np.linalg.norm(p.positions[Joint.HEAD] - head) < 0.15
                below = head[1] - p.positions[Joint.PELVIS][1]
                assert 0.3 < below < 0.9
                horizontal = p.positions[Joint.PELVIS][[0, 2]] - head[[0, 2]]
                assert np.linalg.norm(horizontal) < 0.3
            assert server.metrics.value("posecast_players") == 2
            await three.close()
            await four.close()

    asyncio.run(scenario())


def test_a_server_without_the_headset_only_model_refuses_hmd3() -> None:
    async def scenario() -> None:
        cfg = make_cfg(layouts="hmd3+waist")
        async with serving(cfg, _factory) as server:
            c = await Client.open(server.port)
            err = await c.hello(token("r1", "q"), layout="hmd3")
            assert isinstance(err, Error) and err.code == "LAYOUT_UNSUPPORTED" and err.fatal

    asyncio.run(scenario())
