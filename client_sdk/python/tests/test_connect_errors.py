"""What connect and join raise when they cannot go on: the SDK's own errors, never the
transport's. A URL or token the client cannot use is a ConfigInvalidError before any
dialing; a server that cannot be reached or refuses the upgrade is a ConnectFailedError
(the transport's exception as its cause) naming the URL, with a hint; reconnects go on
after it and give up with it. The servers here are in-process: a scripted posecast peer
(websockets), an HTTP refusal, a silent TCP listener, a refused port."""

from __future__ import annotations

import asyncio
import contextlib
import socket
import ssl
from collections.abc import AsyncIterator, Callable, Coroutine
from typing import Any

import pytest
from websockets.asyncio.server import Server, ServerConnection, serve
from websockets.exceptions import ConnectionClosed, InvalidStatus
from websockets.http11 import Request, Response

import posecast_client as pc
import posecast_client.client as client_mod
from posecast_client.cli.common import connect_patiently
from posecast_client.codec import decode, encode
from posecast_client.errors import (
    ConfigInvalidError,
    ConnectFailedError,
    ConnectionLostError,
    TokenProviderError,
)
from posecast_client.protocol import Hello, Limits, Member, Welcome
from posecast_client.session import is_retryable


def run(coro: Coroutine[Any, Any, None]) -> None:
    asyncio.run(asyncio.wait_for(coro, 30.0))


def refused_url() -> str:
    """A loopback URL nothing listens on: a port bound, then closed."""
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    return f"ws://127.0.0.1:{port}/"


def url_of(server: Server, scheme: str = "ws") -> str:
    port = next(iter(server.sockets)).getsockname()[1]
    return f"{scheme}://127.0.0.1:{port}/"


@contextlib.asynccontextmanager
async def peer(
    on_hello: str = "welcome",
    refuse: Callable[[], int | None] = lambda: None,
    paths: list[str] | None = None,
) -> AsyncIterator[Server]:
    """A posecast v1 server in this process. ``on_hello``: ``welcome`` (join), ``drop``
    (welcome, then close), ``close`` (close without a word) or ``silent`` (say nothing).
    ``refuse``: an HTTP status to refuse the upgrade with, asked at every connection
    (None: go on). ``paths``: gets each upgrade request's path."""

    def gate(conn: ServerConnection, request: Request) -> Response | None:
        if paths is not None:
            paths.append(request.path)
        status = refuse()
        return None if status is None else conn.respond(status, "too many connection attempts\n")

    async def handler(ws: ServerConnection) -> None:
        with contextlib.suppress(ConnectionClosed):
            async for data in ws:
                msg = decode(data if isinstance(data, bytes) else data.encode())
                if not isinstance(msg, Hello):
                    continue
                if on_hello == "close":
                    await ws.close()
                elif on_hello in ("welcome", "drop"):
                    members = (Member("p1", msg.name),)
                    welcome = Welcome(1, "p1", "s1", "player", msg.room, 0.0, 60.0, 2, members,
                                      Limits())  # fmt: skip
                    await ws.send(encode(welcome))
                    if on_hello == "drop":
                        await ws.close()

    async with serve(handler, "127.0.0.1", 0, subprotocols=["posecast.v1"],  # type: ignore[list-item]
                     process_request=gate) as server:  # fmt: skip
        yield server


@contextlib.contextmanager
def dialing_counted(monkeypatch: pytest.MonkeyPatch) -> Any:
    """Count the client's calls of the WebSocket library's connect."""
    calls: list[str] = []
    real = client_mod.ws_connect

    def counting(url: str, **kw: Any) -> Any:
        calls.append(url)
        return real(url, **kw)

    monkeypatch.setattr(client_mod, "ws_connect", counting)
    yield calls


# --- a URL or a token the client cannot use: refused before dialing ---------------------------


@pytest.mark.parametrize(
    ("url", "words"),
    [
        ("http://127.0.0.1:8765/", "use ws://127.0.0.1:8765/"),  # the reviewer's case
        ("https://posecast.example/v1", "use wss://posecast.example/v1"),
        ("localhost:8765", "did you mean ws://localhost:8765/?"),
        ("127.0.0.1:8765", "did you mean ws://127.0.0.1:8765/?"),
        ("ftp://127.0.0.1/", "not a WebSocket URL"),
        ("ws://", "names no host"),
        ("ws://127.0.0.1:99999/", "bad port"),
        ("ws://127.0.0.1:8765/#room", "#fragment"),
        ("ws://127.0.0.1:0/", "bad port (0)"),
        ("ws://[::1", "not a usable URL"),  # urlsplit's own ValueError
        ("ws://[::1:8765/", "not a usable URL"),
        ("", "no server URL (got an empty string)"),
        (None, "no server URL (got None)"),  # os.environ.get of an unset variable
    ],
)
def test_a_url_the_client_cannot_dial_is_refused_before_dialing(
    monkeypatch: pytest.MonkeyPatch, url: Any, words: str
) -> None:
    with dialing_counted(monkeypatch) as calls:
        with pytest.raises(ConfigInvalidError) as info:
            pc.connect(url, "token")  # at the call, before any await
        with pytest.raises(ConfigInvalidError):  # one bad URL among good ones too
            pc.connect(["ws://127.0.0.1:8765/", url], "token")
    assert calls == []
    exc = info.value
    assert isinstance(exc, pc.PosecastClientError) and isinstance(exc, ValueError)
    assert words in str(exc) and "(hint: " in str(exc) and exc.hint in str(exc)
    assert not is_retryable(exc)


@pytest.mark.parametrize(
    ("url", "stored"),
    [
        ("ws://[::1]:8765/", "ws://[::1]:8765/"),  # an IPv6 literal
        ("wss://[2001:db8::1]/posecast", "wss://[2001:db8::1]/posecast"),
        ("ws://127.0.0.1:8765/rooms/lobby?x=1&y=two", "ws://127.0.0.1:8765/rooms/lobby?x=1&y=two"),
        ("WS://127.0.0.1:8765/", "WS://127.0.0.1:8765/"),  # schemes are case-insensitive
        ("Wss://posecast.example/", "Wss://posecast.example/"),
        ("ws://bücher.example:8765/", "ws://bücher.example:8765/"),  # a unicode host
        ("ws://localhost:65535/", "ws://localhost:65535/"),
        ("ws://h:1/", "ws://h:1/"),
        ("ws://user:pw@h/", "ws://user:pw@h/"),
        ("ws://h:8765/ ", "ws://h:8765/"),  # what the client stores and dials: stripped
        ("\t ws://h:8765/\n", "ws://h:8765/"),
    ],
)
def test_a_good_url_is_taken(url: str, stored: str) -> None:
    """A regression refusing URLs a user may well pass must fail here."""
    assert client_mod.check_url(url) == stored
    assert client_mod.Client(url, "token").urls == (stored,)
    assert client_mod.Client([url, "ws://h2/"], "token").urls == (stored, "ws://h2/")


def test_the_client_dials_the_stripped_url(monkeypatch: pytest.MonkeyPatch) -> None:
    """'ws://h:8765/ ' was checked stripped but dialed as given: request path '/ '."""
    paths: list[str] = []

    async def main() -> None:
        async with peer(paths=paths) as server:
            with dialing_counted(monkeypatch) as calls:
                async with pc.connect(f" {url_of(server)} ", "token") as client:
                    await client.join("lobby", "Ada")
            assert calls == [url_of(server)]

    run(main())
    assert paths == ["/"]


def test_several_urls_may_come_as_any_iterable() -> None:
    """A generator or a set of URLs was taken as one URL and refused as 'a value of
    type generator'; a multi-URL input is materialised once."""
    urls = ["ws://a:1/", "ws://b:2/"]
    assert client_mod.Client(iter(urls), "token").urls == tuple(urls)
    assert client_mod.Client((u for u in urls), "token").urls == tuple(urls)
    assert client_mod.Client({"ws://a:1/"}, "token").urls == ("ws://a:1/",)
    assert client_mod.Client(dict.fromkeys(urls), "token").urls == tuple(urls)
    with pytest.raises(ConfigInvalidError, match="no server URL"):
        client_mod.Client(iter([]), "token")
    with pytest.raises(ConfigInvalidError, match="got a value of type bytes"):
        client_mod.Client([b"ws://a:1/"], "token")  # type: ignore[list-item]


@pytest.mark.parametrize(
    ("token", "got"),
    [
        (None, "None"),
        ("", "an empty string"),
        ("  ", "a blank string"),
        (b"tok", "a value of type bytes"),
    ],
)
def test_no_token_is_refused_before_dialing(
    monkeypatch: pytest.MonkeyPatch, token: Any, got: str
) -> None:
    with dialing_counted(monkeypatch) as calls, pytest.raises(ConfigInvalidError) as info:
        pc.connect("ws://127.0.0.1:8765/", token)
    assert calls == []
    assert f"no token (got {got})" in str(info.value)
    assert "unset environment variable" in info.value.hint


def test_a_token_function_returning_nothing_is_refused_at_join() -> None:
    async def main() -> None:
        async with peer() as server, pc.connect(url_of(server), lambda: None) as client:
            with pytest.raises(ConfigInvalidError, match="the token function returned None"):
                await client.join("lobby", "Ada")

    run(main())


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


def test_the_first_join_raises_token_provider_error() -> None:
    async def fails() -> str:
        raise OSError("token endpoint unreachable")

    async def main() -> None:
        async with peer() as server, pc.connect(url_of(server), fails) as client:
            with pytest.raises(TokenProviderError) as info:
                await client.join("lobby", "Ada")
        assert isinstance(info.value.__cause__, OSError) and is_retryable(info.value)

    run(main())


# --- the server cannot be reached, or refuses ---------------------------------------------------


def test_a_refused_port_raises_connect_failed_error() -> None:
    url = refused_url()

    async def main() -> None:
        with pytest.raises(ConnectFailedError) as info:
            await pc.connect(url, "token")
        exc = info.value
        assert isinstance(exc, ConnectionLostError) and isinstance(exc, pc.PosecastClientError)
        assert isinstance(exc.__cause__, ConnectionRefusedError)
        assert exc.url == url and exc.status is None and exc.retryable
        assert str(exc).startswith(f"could not connect to {url}: connection refused")
        assert "posecast serve --dev" in exc.hint and exc.hint in str(exc)

    run(main())


def test_a_host_that_does_not_resolve_raises_connect_failed_error() -> None:
    """RFC 6761: a .invalid name never resolves. The machine's resolver says so at once
    (a gaierror) or, offline, may not answer within open_timeout_s: either is a
    ConnectFailedError naming the URL."""
    url = "ws://no-such-host.invalid/"

    async def main() -> None:
        with pytest.raises(ConnectFailedError) as info:
            await pc.connect(url, "token", open_timeout_s=3.0)
        assert info.value.url == url

    run(main())


@pytest.mark.parametrize("status", [429, 503, 404])
def test_an_http_refusal_of_the_upgrade_carries_its_status(status: int) -> None:
    async def main() -> None:
        async with peer(refuse=lambda: status) as server:
            with pytest.raises(ConnectFailedError) as info:
                await pc.connect(url_of(server), "token")
        exc = info.value
        assert exc.status == status and isinstance(exc.__cause__, InvalidStatus)
        assert f"HTTP {status} (too many connection attempts)" in str(exc)
        assert ("back-off" if status == 503 else "back off" if status == 429 else "endpoint") in (
            exc.hint
        )

    run(main())


@pytest.mark.parametrize("answer", [b"HTTP/1.1 400 Bad Request\r\n\r\n", b""])
def test_tls_to_a_server_without_it_raises_connect_failed_error(answer: bytes) -> None:
    """wss:// to a plain HTTP port: it answers in clear text, or hangs up."""

    async def plain(reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        await reader.read(1)  # the TLS ClientHello
        writer.write(answer)
        await writer.drain()
        writer.transport.abort()

    async def main() -> None:
        server = await asyncio.start_server(plain, "127.0.0.1", 0)
        async with server:
            port = server.sockets[0].getsockname()[1]
            with pytest.raises(ConnectFailedError, match="TLS failed") as info:
                await pc.connect(f"wss://127.0.0.1:{port}/", "token")
        assert isinstance(info.value.__cause__, ssl.SSLError | ConnectionResetError)
        assert "without TLS takes ws://" in info.value.hint

    run(main())


def test_no_handshake_in_time_raises_connect_failed_error() -> None:
    async def main() -> None:
        accepted: list[asyncio.StreamWriter] = []  # a listener that never answers
        silent = await asyncio.start_server(lambda r, w: accepted.append(w), "127.0.0.1", 0)
        async with silent:
            port = silent.sockets[0].getsockname()[1]
            with pytest.raises(ConnectFailedError, match="no WebSocket handshake") as info:
                await pc.connect(f"ws://127.0.0.1:{port}/", "token", open_timeout_s=0.2)
            for w in accepted:
                w.close()
        assert isinstance(info.value.__cause__, TimeoutError)

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


# --- reconnecting --------------------------------------------------------------------------------


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


def test_connect_patiently_retries_429_and_503_only() -> None:
    refusals = [503, 429]

    async def main() -> None:
        async with peer(refuse=lambda: refusals.pop(0) if refusals else None) as server:
            client = await connect_patiently(url_of(server), "token")
            await client.close()
        assert refusals == []  # both refusals were met and retried
        refusals.append(404)
        async with peer(refuse=lambda: refusals.pop(0) if refusals else None) as server:
            with pytest.raises(ConnectFailedError) as info:
                await connect_patiently(url_of(server), "token")
        assert info.value.status == 404 and refusals == []  # not retried

    run(main())
