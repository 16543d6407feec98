"""SIGTERM while the server is under load: every client hears ``bye``
(``SERVER_SHUTDOWN``), the process exits 0 within ``drain_timeout_s``, and no
healthy client lost a pose before its ``bye``."""

from __future__ import annotations

import asyncio
import contextlib
import signal
import time

import posecast_client as pc
import pytest

from posecast.online.protocol.messages import Bye, Welcome
from tests.online.conftest import token
from tests.online.wsclient import Client
from tests.system.reliability.fault_helpers import ServerProc, fmt, report, seqs_in

pytestmark = pytest.mark.timeout(120)
DRAIN_TIMEOUT_S = 5.0  # drain_timeout_s, the server default (online/config.py)
ROOMS, PER_ROOM = 2, 4


def test_sigterm_under_load_says_bye_to_everyone_and_exits_cleanly() -> None:
    server = ServerProc()

    async def scenario() -> None:
        clients: dict[str, list[Client]] = {}
        for r in range(ROOMS):
            room = f"room{r}"
            for i in range(PER_ROOM):
                cl = await Client.open(server.port)
                name = f"p{r}{i}"
                assert isinstance(await cl.hello(token(room, name), room=room, name=name), Welcome)
                cl.stream(seed=r * PER_ROOM + i)
                clients.setdefault(room, []).append(cl)
        sdk = await pc.connect(server.url, token("room0", "sdk"), reconnect=False)
        await sdk.join("room0", "SDK")
        streaming = asyncio.create_task(sdk.stream(pc.WalkSource(seconds=30.0, loop=True)))

        async def sdk_outcome() -> BaseException | None:
            try:
                async for _ in sdk.events():
                    pass
            except pc.PosecastClientError as exc:
                return exc
            return None

        sdk_end = asyncio.create_task(sdk_outcome())
        await asyncio.sleep(2.0)  # load: 9 players at 60 Hz, 2 rooms
        frames = server.metric("posecast_frames_total")
        t_term = time.monotonic()
        server.proc.send_signal(signal.SIGTERM)
        everyone = [cl for members in clients.values() for cl in members]
        bye_s = []
        for cl in everyone:
            await cl.wait_for(lambda m: isinstance(m, Bye), DRAIN_TIMEOUT_S)
            bye_s.append(time.monotonic() - t_term)
        code = await asyncio.to_thread(server.proc.wait, DRAIN_TIMEOUT_S + 5)
        exit_s = time.monotonic() - t_term
        sdk_exc = await asyncio.wait_for(sdk_end, 5)
        streaming.cancel()
        with contextlib.suppress(asyncio.CancelledError, pc.PosecastClientError):
            await streaming
        await sdk.close()

        byes = [[m for m in cl.messages if isinstance(m, Bye)] for cl in everyone]
        compared = lost = 0
        for members in clients.values():
            t_end = min(cl.poses()[-1].t for cl in members) - 0.1  # shutdown drops unsent
            t_start = max(cl.poses()[0].t for cl in members) + 0.2
            seen = [seqs_in(cl.poses(), t_start, t_end) for cl in members]
            union = set().union(*seen)
            compared += len(union)
            lost += sum(len(union - s) for s in seen)
        closed = sum(cl.closed.is_set() for cl in everyone)
        for cl in everyone:
            await cl.close()
        report(
            "SIGTERM under load",
            frames_accepted=int(frames),
            bye_after_s=fmt(sorted(bye_s)[:: max(1, len(bye_s) // 4)], 3),
            last_bye_s=f"{max(bye_s):.3f}",
            exit_code=code,
            exit_after_s=f"{exit_s:.2f}",
            sdk_saw=type(sdk_exc).__name__,
            clients_closed=f"{closed}/{len(everyone)}",
            healthy_poses_compared=compared,
            healthy_lost=lost,
        )
        assert code == 0, code
        assert exit_s < DRAIN_TIMEOUT_S, exit_s  # everyone drained before the deadline
        assert all(b == [Bye("SERVER_SHUTDOWN")] for b in byes), byes
        assert all(cl.messages[-1] == Bye("SERVER_SHUTDOWN") for cl in everyone)  # the last word
        assert closed == len(everyone)
        assert isinstance(sdk_exc, pc.errors.ServerShutdownError), sdk_exc
        assert lost == 0 and compared > ROOMS * PER_ROOM * 60, (lost, compared)

    try:
        asyncio.run(scenario())
    finally:
        server.close()
