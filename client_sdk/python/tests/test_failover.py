"""Failover across several server URLs: the first connection skips a dead URL, and a
client whose server dies rejoins through the next URL in its list."""

from __future__ import annotations

import asyncio
import contextlib
import secrets
import signal
import socket
from collections.abc import Callable
from pathlib import Path

import pytest

import posecast_client as pc
from sdk_helpers import EventLog, start_server


def dead_url() -> str:
    """A loopback URL nothing listens on (the port was free a moment ago)."""
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    return f"ws://127.0.0.1:{port}/"


def newer_than(seq: int) -> Callable[[pc.Event], bool]:
    return lambda e: isinstance(e, pc.Pose) and e.seq > seq


def test_a_url_list_is_tried_in_order_and_a_dead_server_fails_over(
    tmp_path: Path, uid: str
) -> None:
    secret = secrets.token_urlsafe(24)
    first = start_server(tmp_path / "a.log", secret=secret)
    second = start_server(tmp_path / "b.log", secret=secret)
    room, player = f"room-{uid}", f"p-{uid}"

    async def main() -> None:
        token = first.token(room, player)
        urls = [dead_url(), first.url, second.url]
        client = await pc.connect(urls, token, backoff_initial_s=0.1, backoff_max_s=0.4)
        async with client:
            assert client.url == first.url  # the dead one was skipped
            await client.join(room, "P")
            events = EventLog(client)
            streaming = asyncio.create_task(client.stream(pc.WalkSource(seconds=30.0, loop=True)))
            await events.wait_for(lambda e: isinstance(e, pc.Pose))
            mark = len(events.events)
            last_seq = max(e.seq for e in events.events if isinstance(e, pc.Pose))
            await asyncio.to_thread(first.stop, signal.SIGKILL)
            back = await events.wait_for(lambda e: isinstance(e, pc.Welcome), start=mark)
            assert isinstance(back, pc.Welcome) and back.player == player
            assert client.url == second.url  # the next URL after the lost one
            await events.wait_for(newer_than(last_seq), start=mark)
            assert client.stats.reconnects == 1
            streaming.cancel()
            with contextlib.suppress(asyncio.CancelledError):
                await streaming
            events.stop()

    try:
        asyncio.run(asyncio.wait_for(main(), 30.0))
    finally:
        first.stop()
        second.stop()


def test_no_url_is_refused() -> None:
    with pytest.raises(ValueError, match="no server URL"):
        pc.Client([], "token")


def test_when_no_url_opens_the_last_error_is_raised() -> None:
    async def main() -> None:
        urls = [dead_url(), dead_url()]
        with pytest.raises(pc.ConnectFailedError) as info:
            await pc.connect(urls, "token")
        assert info.value.url == urls[-1] and isinstance(info.value.__cause__, OSError)

    asyncio.run(main())
