"""The connection behind a client (``link.py``): the join's handshake and the token
function, reconnecting and rejoining, and giving up. In-process peers for the error
paths; a real ``posecast serve --dev``, restarted, for reconnect-and-resume."""

from __future__ import annotations

import asyncio
import contextlib
import secrets
import signal
from collections.abc import Callable, Coroutine
from pathlib import Path
from typing import Any

import pytest
from websockets.exceptions import ConnectionClosed

import posecast_client as pc
from peer_helpers import peer, url_of
from posecast_client import errors
from posecast_client.errors import (
    ConfigInvalidError,
    ConnectFailedError,
    ConnectionLostError,
    TokenProviderError,
)
from posecast_client.protocol import Welcome
from posecast_client.session import is_retryable
from sdk_helpers import EventLog, start_server


def run(coro: Coroutine[Any, Any, None], timeout_s: float = 30.0) -> None:
    asyncio.run(asyncio.wait_for(coro, timeout_s))


# --- the join: the token function, a join cut short -------------------------------------------


def test_a_token_function_returning_nothing_is_refused_at_join() -> None:
    async def main() -> None:
        async with peer() as server, pc.connect(url_of(server), lambda: None) as client:
            with pytest.raises(ConfigInvalidError, match="the token function returned None"):
                await client.join("lobby", "Ada")

    run(main())


def test_the_first_join_raises_token_provider_error() -> None:
    async def fails() -> str:
        raise OSError("token endpoint unreachable")

    async def main() -> None:
        async with peer() as server, pc.connect(url_of(server), fails) as client:
            with pytest.raises(TokenProviderError) as info:
                await client.join("lobby", "Ada")
        assert isinstance(info.value.__cause__, OSError) and is_retryable(info.value)

    run(main())


@pytest.mark.parametrize(("on_hello", "words"), [("close", "closed the connection during the join"),
                                                 ("silent", "no welcome from")])  # fmt: skip
def test_a_join_cut_short_raises_connection_lost_error(on_hello: str, words: str) -> None:
    async def main() -> None:
        async with (
            peer(on_hello) as server,
            pc.connect(url_of(server), "token", join_timeout_s=0.2) as client,
        ):
            with pytest.raises(ConnectionLostError, match=words) as info:
                await client.join("lobby", "Ada")
        assert isinstance(info.value.__cause__, ConnectionClosed | TimeoutError)

    run(main())


# --- reconnecting: a fresh token each rejoin, back-off, giving up, resuming -------------------


def test_a_token_function_giving_no_token_on_a_rejoin_ends_the_session_with_it() -> None:
    """The reconnect task met an error it did not expect and died unseen: events() waited
    for good. Now the session ends with the error, as with any a retry cannot fix."""
    tokens: list[str | None] = ["tok", None]

    async def main() -> None:
        async with peer("drop") as server:
            client = await pc.connect(url_of(server), lambda: tokens.pop(0),
                                      backoff_initial_s=0.01, ping_interval_s=0)  # fmt: skip
            async with client:
                await client.join("lobby", "Ada")
                with pytest.raises(ConfigInvalidError, match="the token function returned None"):
                    async for _ in client.events():
                        pass
        assert tokens == []

    run(main())


def test_a_token_function_that_raises_is_retried_on_a_rejoin() -> None:
    """A brief outage of the backend's token endpoint killed the client: the token
    function's error ended the session. It is a TokenProviderError now, retried as a
    lost connection: the rejoin after two failures goes on."""
    calls: list[int] = []

    def token() -> str:
        calls.append(1)
        if len(calls) in (2, 3):  # the first rejoin's two tries
            raise RuntimeError("token endpoint: HTTP 503")
        return "tok"

    async def main() -> None:
        async with peer("drop") as server:
            client = await pc.connect(url_of(server), token, backoff_initial_s=0.01,
                                      ping_interval_s=0, max_reconnect_attempts=5)  # fmt: skip
            async with client:
                await client.join("lobby", "Ada")
                causes = []
                async for event in client.events():
                    if isinstance(event, pc.Reconnecting):
                        causes.append(event.cause)
                    elif isinstance(event, Welcome):
                        break  # rejoined
        assert len(calls) == 4
        assert [type(c) for c in causes] == [ConnectionLostError, TokenProviderError,
                                             TokenProviderError]  # fmt: skip
        assert isinstance(causes[1].__cause__, RuntimeError) and causes[1].retryable
        assert "the token function raised RuntimeError('token endpoint: HTTP 503')" in str(
            causes[1]
        )

    run(main())


def test_a_token_function_that_keeps_raising_gives_up_with_its_error_as_cause() -> None:
    calls: list[int] = []

    def token() -> str:
        calls.append(1)
        if len(calls) > 1:
            raise RuntimeError("token endpoint down")
        return "tok"

    async def main() -> None:
        async with peer("drop") as server:
            client = await pc.connect(url_of(server), token, backoff_initial_s=0.01,
                                      ping_interval_s=0, max_reconnect_attempts=3)  # fmt: skip
            async with client:
                await client.join("lobby", "Ada")
                with pytest.raises(TokenProviderError) as info:
                    async for _ in client.events():
                        pass
        assert isinstance(info.value.__cause__, RuntimeError)
        assert len(calls) == 1 + 3

    run(main())


def test_reconnects_retry_a_refused_server_then_give_up_with_connect_failed_error() -> None:
    async def main() -> None:
        async with peer() as server:
            url = url_of(server)
            client = await pc.connect(url, "token", backoff_initial_s=0.01, backoff_max_s=0.02,
                                      max_reconnect_attempts=3, ping_interval_s=0)  # fmt: skip
            await client.join("lobby", "Ada")
        # The server is gone and its port refuses: every attempt fails, and is retried.
        causes: list[BaseException] = []
        with pytest.raises(ConnectFailedError) as info:
            async for event in client.events():
                if isinstance(event, pc.Reconnecting):
                    causes.append(event.cause)
        await client.close()
        assert len(causes) == 3  # attempts 1, 2, 3, then it gives up
        assert isinstance(causes[0], ConnectionLostError)  # the drop itself
        assert all(isinstance(c, ConnectFailedError) and c.url == url for c in causes[1:])
        assert info.value.url == url and isinstance(info.value.__cause__, OSError)

    run(main())


def newer_than(seq: int) -> Callable[[pc.Event], bool]:
    return lambda e: isinstance(e, pc.Pose) and e.seq > seq


def test_reconnect_and_resume_across_server_restarts(tmp_path: Path, uid: str) -> None:
    """A graceful restart (bye SERVER_SHUTDOWN) and a crash (SIGKILL): each time the
    client backs off, rejoins the same room with the same token, and its seqs go on."""
    log = tmp_path / "server.log"
    secret = secrets.token_urlsafe(24)
    first = start_server(log, secret=secret)
    servers = [first]
    room, player = f"room-{uid}", f"p-{uid}"

    async def main() -> None:
        token = first.token(room, player)
        client = await pc.connect(first.url, token, backoff_initial_s=0.1, backoff_max_s=0.4)
        async with client:
            await client.join(room, "P")
            events = EventLog(client)
            streaming = asyncio.create_task(client.stream(pc.WalkSource(seconds=30.0, loop=True)))
            for how, cause in ((signal.SIGTERM, errors.ServerShutdownError),
                               (signal.SIGKILL, errors.ConnectionLostError)):  # fmt: skip
                mark = len(events.events)
                await events.wait_for(lambda e: isinstance(e, pc.Pose), start=mark)
                last_seq = max(e.seq for e in events.events if isinstance(e, pc.Pose))
                await asyncio.to_thread(servers[-1].stop, how)  # the client keeps reading
                lost = await events.wait_for(lambda e: isinstance(e, pc.Reconnecting), start=mark)
                assert isinstance(lost, pc.Reconnecting) and isinstance(lost.cause, cause)
                assert not client.connected
                await asyncio.sleep(0.3)
                servers.append(
                    await asyncio.to_thread(start_server, log, port=first.port, secret=secret)
                )
                back = await events.wait_for(lambda e: isinstance(e, pc.Welcome), start=mark)
                assert isinstance(back, pc.Welcome) and back.player == player
                pose = await events.wait_for(newer_than(last_seq), start=mark)
                assert isinstance(pose, pc.Pose) and client.sent_at(pose.seq) is not None
            assert client.stats.reconnects == 2 and client.connected
            streaming.cancel()
            with contextlib.suppress(asyncio.CancelledError):
                await streaming
            events.stop()

    try:
        run(main(), 60.0)
    finally:
        for s in servers:
            s.stop()
