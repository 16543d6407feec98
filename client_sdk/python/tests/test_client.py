"""The asyncio client against a real ``posecast serve --dev``: join, stream, clock
sync, typed refusals, kicks, closing; and the options a client takes (several URLs).
Reconnect-and-resume across server restarts is ``test_link.py``'s."""

from __future__ import annotations

import asyncio
import time
from collections.abc import Callable, Coroutine
from typing import Any

import numpy as np
import pytest

import posecast_client as pc
from posecast_client import errors
from posecast_client.errors import ConfigInvalidError
from sdk_helpers import DevServer, EventLog


def run(coro: Coroutine[Any, Any, None], timeout_s: float = 30.0) -> None:
    asyncio.run(asyncio.wait_for(coro, timeout_s))


def test_join_stream_receive_and_sync_clocks(dev_server: DevServer, uid: str) -> None:
    room = f"room-{uid}"

    async def main() -> None:
        ada = await pc.connect(dev_server.url, dev_server.token(room, f"ada-{uid}"))
        bob = await pc.connect(dev_server.url, dev_server.token(room, f"bob-{uid}"))
        async with ada, bob:
            welcome = await ada.join(room, "Ada")
            assert (welcome.player, welcome.role, welcome.room) == (f"ada-{uid}", "player", room)
            assert welcome.limits.max_players >= 1 and welcome.rate_hz == 60.0
            ada_log = EventLog(ada)
            await bob.join(room, "Bob")
            streaming = asyncio.create_task(ada.stream(pc.WalkSource(seconds=1.5)))
            bob_poses = [e async for e in bob.events(until=streaming) if isinstance(e, pc.Pose)]
            assert await streaming == 90
            await ada_log.wait_for(lambda e: isinstance(e, pc.Pose) and e.seq >= 60)
            own = [e for e in ada_log.events if isinstance(e, pc.Pose)]
            assert {p.player for p in own} == {f"ada-{uid}"}
            assert all(ada.sent_at(p.seq) is not None for p in own)  # seq names a sent frame
            assert len(bob_poses) > 40  # bob sees ada's avatar
            assert np.all(np.diff([p.seq for p in own]) > 0)
            seen = [(e.event, e.player) for e in ada_log.events if isinstance(e, pc.Presence)]
            assert seen[0] == ("join", f"bob-{uid}")  # (then stale: bob sends no frames)
            # Both clocks are this machine's monotonic clock: the offset is about 0.
            offset, rtt = ada.clock.offset_s, ada.clock.rtt_s
            assert offset is not None and rtt is not None
            assert abs(offset) <= rtt / 2 + 0.002 and rtt < 0.25
            ada_log.stop()

    run(main())


@pytest.mark.parametrize(
    ("case", "expected"),
    [
        ("other_room", errors.ForbiddenError),
        ("wrong_secret", errors.UnauthenticatedError),
        ("expired", errors.TokenExpiredError),
    ],
)
def test_refusals_raise_typed_errors(
    dev_server: DevServer, uid: str, case: str, expected: type[errors.ProtocolError]
) -> None:
    room = f"room-{uid}"
    tokens: dict[str, Callable[[], str]] = {
        "other_room": lambda: dev_server.token("elsewhere", f"p-{uid}"),
        "wrong_secret": lambda: pc.mint_token("n" * 32, room=room, player="p"),
        "expired": lambda: dev_server.token(room, f"p-{uid}", now=time.time() - 7200),
    }

    async def main() -> None:
        async with pc.connect(dev_server.url, tokens[case]()) as client:
            with pytest.raises(expected) as info:
                await client.join(room, "P")
            assert info.value.fatal and not info.value.retryable

    run(main())


def test_a_headset_only_player_streams_without_a_waist(dev_server: DevServer, uid: str) -> None:
    """``layout="hmd3"``: frames with the waist slot not valid; the room gets its avatar
    (the server's headset-only model predicts the pelvis)."""
    room = f"room-{uid}"

    async def main() -> None:
        quest = await pc.connect(dev_server.url, dev_server.token(room, f"quest-{uid}"))
        bob = await pc.connect(dev_server.url, dev_server.token(room, f"bob-{uid}"))
        async with quest, bob:
            await quest.join(room, "Quest", layout="hmd3")
            await bob.join(room, "Bob")

            async def send() -> int:
                n = 0
                async for sample in pc.WalkSource(seconds=1.5):
                    pos, quat = sample.positions.copy(), sample.orientations.copy()
                    pos[3], quat[3] = 0.0, (0.0, 0.0, 0.0, 1.0)  # no waist tracker
                    await quest.send_frame(pos, quat, valid=0b0111)
                    n += 1
                return n

            sending = asyncio.create_task(send())
            poses = [e async for e in bob.events(until=sending) if isinstance(e, pc.Pose)]
            assert await sending == 90
            assert len(poses) > 40 and {p.player for p in poses} == {f"quest-{uid}"}
            head_y = np.array([p.positions[pc.Joint.HEAD][1] for p in poses])
            pelvis_y = np.array([p.positions[pc.Joint.PELVIS][1] for p in poses])
            assert np.all(head_y - pelvis_y > 0.3)  # a body hangs under the headset

    run(main())


def test_a_kick_ends_the_session_for_good(dev_server: DevServer, uid: str) -> None:
    room = f"room-{uid}"

    async def main() -> None:
        player = await pc.connect(dev_server.url, dev_server.token(room, f"p-{uid}"),
                                  backoff_initial_s=0.05)  # fmt: skip
        backend = await pc.connect(dev_server.url, dev_server.token(room, f"b-{uid}", "backend"))
        async with player, backend:
            await player.join(room, "P")
            await backend.join(room, "Ops")
            await player.send_frame(np.full((4, 3), 1.0), np.tile([0, 0, 0, 1.0], (4, 1)))
            assert await backend.send(pc.Kick(f"p-{uid}", "cheating"))
            with pytest.raises(errors.KickedError, match="cheating"):
                async for _ in player.events():
                    pass
            with pytest.raises(errors.KickedError):
                await player.send_frame(np.zeros((4, 3)), np.tile([0, 0, 0, 1.0], (4, 1)))
            assert player.stats.reconnects == 0

    run(main())


def test_the_readme_loop_reports_a_kick_once_and_a_failed_stream(
    dev_server: DevServer, uid: str
) -> None:
    """The README's pattern (stream in a task, read events until it is done): a kick
    ended the read with KickedError, and the stream task, failing of the same kick a
    moment later, was left for asyncio to report as "Task exception was never
    retrieved"; a stream that failed on its own ended the read as if it had finished."""
    import gc

    room = f"room-{uid}"

    class Broken(pc.WalkSource):
        async def __aiter__(self):  # type: ignore[no-untyped-def,override]
            yield await anext(aiter(pc.WalkSource(seconds=0.1)))
            raise OSError("the tracker went away")

    async def main() -> None:
        unreported: list[dict[str, Any]] = []
        asyncio.get_running_loop().set_exception_handler(lambda _, ctx: unreported.append(ctx))
        player = await pc.connect(dev_server.url, dev_server.token(room, f"p-{uid}"))
        backend = await pc.connect(dev_server.url, dev_server.token(room, f"b-{uid}", "backend"))
        async with player, backend:
            await player.join(room, "P")
            await backend.join(room, "Ops")
            streaming = asyncio.create_task(player.stream(pc.WalkSource(seconds=10.0)))
            await asyncio.sleep(0.2)
            assert await backend.send(pc.Kick(f"p-{uid}", "cheating"))
            with pytest.raises(errors.KickedError):
                async for _ in player.events(until=streaming):
                    pass
            while not streaming.done():  # it fails of the kick too; nobody awaits it
                await asyncio.sleep(0.01)
        del streaming, player  # the kick's traceback on the client holds the task
        gc.collect()
        await asyncio.sleep(0)
        assert unreported == []
        other = await pc.connect(dev_server.url, dev_server.token(room, f"q-{uid}"))
        async with other:
            await other.join(room, "Q")
            failing = asyncio.create_task(other.stream(Broken(seconds=1.0)))
            with pytest.raises(OSError, match="went away"):
                async for _ in other.events(until=failing):
                    pass
        del failing, other
        gc.collect()
        await asyncio.sleep(0)
        assert unreported == []

    run(main())


def test_closed_clients_refuse_to_send(dev_server: DevServer, uid: str) -> None:
    async def main() -> None:
        client = await pc.connect(dev_server.url, dev_server.token("r", f"p-{uid}"))
        await client.join("r", "P")
        await client.close()
        with pytest.raises(pc.ClientClosedError):
            await client.send_frame(np.zeros((4, 3)), np.tile([0, 0, 0, 1.0], (4, 1)))
        assert [e async for e in client.events()] == []

    run(main())


def test_several_urls_may_come_as_any_iterable() -> None:
    """A generator or a set of URLs was taken as one URL and refused as 'a value of
    type generator'; a multi-URL input is materialised once."""
    urls = ["ws://a:1/", "ws://b:2/"]
    assert pc.Client(iter(urls), "token").urls == tuple(urls)
    assert pc.Client((u for u in urls), "token").urls == tuple(urls)
    assert pc.Client({"ws://a:1/"}, "token").urls == ("ws://a:1/",)
    assert pc.Client(dict.fromkeys(urls), "token").urls == tuple(urls)
    with pytest.raises(ConfigInvalidError, match="no server URL"):
        pc.Client(iter([]), "token")
    with pytest.raises(ConfigInvalidError, match="got a value of type bytes"):
        pc.Client([b"ws://a:1/"], "token")  # type: ignore[list-item]
