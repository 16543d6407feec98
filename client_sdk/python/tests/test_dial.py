"""What dialing raises when it cannot go on (``dial.py``): the SDK's own errors, never
the transport's. A URL or token the client cannot use is a ConfigInvalidError before
any dialing; a server that cannot be reached or refuses the upgrade is a
ConnectFailedError (the transport's exception as its cause) naming the URL, with a
hint. The servers here are in-process: a scripted posecast peer (websockets), an HTTP
refusal, a silent TCP listener, a refused port."""

from __future__ import annotations

import asyncio
import contextlib
import ssl
from collections.abc import Coroutine
from typing import Any

import pytest
from websockets.exceptions import InvalidStatus

import posecast_client as pc
from peer_helpers import peer, refused_url, url_of
from posecast_client import dial
from posecast_client.errors import (
    ConfigInvalidError,
    ConnectFailedError,
    ConnectionLostError,
)
from posecast_client.session import is_retryable


def run(coro: Coroutine[Any, Any, None]) -> None:
    asyncio.run(asyncio.wait_for(coro, 30.0))


@contextlib.contextmanager
def dialing_counted(monkeypatch: pytest.MonkeyPatch) -> Any:
    """Count the client's calls of the WebSocket library's connect."""
    calls: list[str] = []
    real = dial.ws_connect

    def counting(url: str, **kw: Any) -> Any:
        calls.append(url)
        return real(url, **kw)

    monkeypatch.setattr(dial, "ws_connect", counting)
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
    assert dial.check_url(url) == stored
    assert pc.Client(url, "token").urls == (stored,)
    assert pc.Client([url, "ws://h2/"], "token").urls == (stored, "ws://h2/")


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


# --- the server cannot be reached, or refuses -------------------------------------------------


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
