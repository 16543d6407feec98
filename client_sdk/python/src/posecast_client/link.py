"""The connection behind a :class:`~posecast_client.client.Client`: one WebSocket kept
joined across drops, moving bytes between it and the pure
:class:`~posecast_client.session.ClientSession`.

**Reconnect and resume.** When a joined connection ends for a retryable reason (the
socket dropped, the server said ``bye`` or sent ``SERVER_SHUTDOWN``, ``TIMED_OUT``,
``SLOW_CONSUMER`` or ``INTERNAL``), the client waits an exponential back-off with
jitter (``backoff_initial_s`` doubling up to ``backoff_max_s``), opens a new
connection and sends the same ``hello`` again: same token (or a fresh one from a
token callable), room, name, layout and rate. Given several URLs (the nodes of one
cluster, ``docs/scale-out.md``), every attempt goes to the next URL in turn, so a
dead node's players come back through another one. Frames sent meanwhile are dropped, not
queued (a newer frame supersedes them), but their ``seq`` is used up, so ``seq``
keeps increasing across connections. Errors that a retry cannot fix (a refused or
expired token, ``FORBIDDEN``, ``ROOM_FULL``, ``KICKED``, ``REPLACED``, ...) end the
client: :meth:`~posecast_client.client.Client.events` and
:meth:`~posecast_client.client.Client.send_frame` raise the typed error.

Three tasks run per client: the connection task (reads, decodes, reconnects), the
pinger (clock sync: four pings right after each join, then one every
``ping_interval_s``) and whatever the application runs itself.

:class:`Link` holds the connection's state (``url``, ``connected``, ``version``,
``welcome``, ``clock``, ``stats``...) and runs those tasks;
:class:`~posecast_client.client.Client` extends it with the application's calls
(``join``, ``send_frame``, ``events``, ``close``...). Dialing one server is
:mod:`posecast_client.dial`'s.
"""

from __future__ import annotations

import asyncio
import contextlib
import inspect
import logging
import random
import time
from collections import deque
from collections.abc import Awaitable, Callable
from typing import Any

from websockets.asyncio.client import ClientConnection
from websockets.exceptions import ConnectionClosed, InvalidHandshake

from posecast_client.clock import ClockSync
from posecast_client.codec import decode, encode
from posecast_client.dial import describe_argument, open_websocket, version_of
from posecast_client.errors import (
    ConfigInvalidError,
    ConnectFailedError,
    ConnectionLostError,
    ProtocolError,
    TokenProviderError,
)
from posecast_client.protocol import Ping, Resync, Welcome
from posecast_client.session import (
    ClientSession,
    Event,
    Reconnecting,
    Stats,
    backoff_delay,
    classify_join_reply,
    is_retryable,
)

log = logging.getLogger("posecast_client")
Token = str | Callable[[], str | Awaitable[str]]


class Link:
    """One server connection (of ``urls``, tried in turn) kept joined across drops: the
    state and the tasks behind a :class:`~posecast_client.client.Client`, whose
    docstring lists the options. Its underscored attributes and methods are shared
    with that subclass and nothing else.
    """

    def __init__(
        self,
        urls: tuple[str, ...],
        token: Token,
        *,
        reconnect: bool,
        backoff_initial_s: float,
        backoff_max_s: float,
        max_reconnect_attempts: int | None,
        ping_interval_s: float,
        open_timeout_s: float,
        join_timeout_s: float,
        keepalive_s: float,
        max_events: int,
        seq0: int,
        protocol: int,
    ) -> None:
        self.urls: tuple[str, ...] = urls
        self._url_index = 0
        self._token = token
        self.reconnect = reconnect
        self.backoff_initial_s, self.backoff_max_s = backoff_initial_s, backoff_max_s
        self.max_reconnect_attempts = max_reconnect_attempts
        self.ping_interval_s = ping_interval_s
        self.open_timeout_s, self.join_timeout_s = open_timeout_s, join_timeout_s
        self.keepalive_s = keepalive_s
        self.protocol = protocol
        self.session = ClientSession(seq0=seq0)
        self._rng = random.Random()
        self._ws: ClientConnection | None = None
        self._hello_args: dict[str, Any] | None = None
        self._events: deque[Event] = deque()
        self._max_events = max_events
        self._wake = asyncio.Event()
        self._joined = asyncio.Event()
        self._tasks: list[asyncio.Task[None]] = []
        self._failure: BaseException | None = None
        self._closing = False

    # --- state -------------------------------------------------------------------------

    @property
    def url(self) -> str:
        """The URL of the current (or last) connection."""
        return self.urls[self._url_index]

    @property
    def welcome(self) -> Welcome | None:
        """The latest ``welcome`` (it changes on every rejoin)."""
        return self.session.welcome

    @property
    def player(self) -> str | None:
        """This client's player id, once joined."""
        return None if self.session.welcome is None else self.session.welcome.player

    @property
    def connected(self) -> bool:
        """Joined right now (False while reconnecting)."""
        return self._joined.is_set()

    @property
    def version(self) -> int:
        """The protocol version of the current (or last) connection: 1 or 2."""
        return self.session.version

    @property
    def clock(self) -> ClockSync:
        """Offset between this client's ``time.monotonic()`` and the server's clock."""
        return self.session.clock

    @property
    def stats(self) -> Stats:
        return self.session.stats

    def sent_at(self, seq: int) -> float | None:
        """``time.monotonic()`` when the frame ``seq`` was sent (the last 1024 frames);
        a pose with that ``seq`` arriving now took ``time.monotonic() - sent_at`` end to
        end, the server's look-ahead included."""
        return self.session.sent_at(seq)

    # --- connecting and joining ----------------------------------------------------------

    async def _open(self) -> ClientConnection:
        return await open_websocket(
            self.url,
            protocol=self.protocol,
            open_timeout_s=self.open_timeout_s,
            keepalive_s=self.keepalive_s,
        )

    async def _open_first(self) -> None:
        """Open the first of ``urls`` that opens (the first connection: never retried).

        Raises:
            ConnectFailedError: none opened; the last URL's failure.
        """
        for i in range(len(self.urls)):
            self._url_index = i
            try:
                self._ws = await self._open()
            except ConnectFailedError:
                if i == len(self.urls) - 1:
                    raise
                continue
            break

    async def _handshake(self, ws: ClientConnection) -> Welcome:
        """Send ``hello`` on ``ws`` and read up to its ``welcome`` (or refusal)."""
        assert self._hello_args is not None
        try:
            token = self._token() if callable(self._token) else self._token
            if inspect.isawaitable(token):
                token = await token
        except Exception as exc:  # the backend's token endpoint down, say: worth a retry
            raise TokenProviderError(f"the token function raised {exc!r}") from exc
        if not (isinstance(token, str) and token.strip()):
            raise ConfigInvalidError(
                f"the token function returned {describe_argument(token)}",
                hint="it must return the join token, a non-empty string",
            )
        version = version_of(ws)
        self.session.connected(version)
        try:
            await ws.send(encode(self.session.hello(token, **self._hello_args)))
            async with asyncio.timeout(self.join_timeout_s):
                while True:
                    data = await ws.recv()
                    if not isinstance(data, bytes):
                        raise ConnectionLostError("the server sent a text message")
                    reply = classify_join_reply(decode(data, version=version))
                    if isinstance(reply, ProtocolError):
                        raise reply
                    if reply is not None:
                        self.session.receive(reply, time.monotonic())
                        return reply
        except ConnectionClosed as exc:
            why = exc.rcvd or "no close frame"
            raise ConnectionLostError(
                f"{self.url} closed the connection during the join ({why})"
            ) from exc
        except TimeoutError as exc:
            raise ConnectionLostError(
                f"no welcome from {self.url} within {self.join_timeout_s} s"
            ) from exc

    def _start(self, ws: ClientConnection) -> None:
        """Joined on ``ws``: start the connection task (and the pinger)."""
        self._joined.set()
        self._tasks = [asyncio.create_task(self._run(ws), name="posecast-client")]
        if self.ping_interval_s > 0:
            self._tasks.append(asyncio.create_task(self._pinger(), name="posecast-pinger"))

    # --- the connection task -------------------------------------------------------------

    async def _run(self, ws: ClientConnection) -> None:
        """Read the joined connection; when it ends, reconnect and rejoin (or give up)."""
        while True:
            cause = await self._read(ws)
            if self._ws is ws:
                self._ws = None
            self._joined.clear()
            if self._closing:
                return
            if not (self.reconnect and _retryable(cause)):
                self._fail(cause)
                return
            log.info("connection lost (%r); reconnecting", cause)
            new = await self._reconnect(cause)
            if new is None:
                return
            ws = self._ws = new
            self._joined.set()

    async def _read(self, ws: ClientConnection) -> BaseException:
        """Decode and dispatch messages until the connection ends; returns why it did."""
        cause: BaseException | None = None
        try:
            async for data in ws:
                if not isinstance(data, bytes):
                    cause = ConnectionLostError("the server sent a text message")
                    await ws.close(1003)
                    break
                try:
                    msg = decode(data, version=self.session.version)
                except ProtocolError as exc:
                    self.session.stats.bad_messages += 1
                    log.warning("skipping a server message: %r", exc)
                    continue
                events, end = self.session.receive_all(msg, time.monotonic(), len(data))
                for event in events:
                    self._push(event)
                if self.session.want_resync:  # a record it could not apply: start afresh
                    self.session.want_resync = False
                    with contextlib.suppress(ConnectionClosed):
                        await ws.send(encode(Resync()))
                if end is not None and cause is None:
                    cause = end  # the server closes right after; keep reading until it does
        except ConnectionClosed as exc:
            if cause is None:
                lost = ConnectionLostError(f"connection closed ({exc.rcvd or 'no close frame'})")
                lost.__cause__ = exc
                cause = lost
        return cause or ConnectionLostError("connection closed")

    async def _reconnect(self, cause: BaseException) -> ClientConnection | None:
        attempt = 0
        while not self._closing:
            attempt += 1
            if self.max_reconnect_attempts is not None and attempt > self.max_reconnect_attempts:
                self._fail(cause)
                return None
            delay = backoff_delay(attempt, self.backoff_initial_s, self.backoff_max_s, self._rng)
            self._push(Reconnecting(attempt, delay, cause))
            await asyncio.sleep(delay)
            self._url_index = (self._url_index + 1) % len(self.urls)  # failover: next node
            ws: ClientConnection | None = None
            try:
                ws = await self._open()
                welcome = await self._handshake(ws)
            except asyncio.CancelledError:  # close() while rejoining: drop the new socket
                if ws is not None:
                    ws.transport.abort()
                raise
            except Exception as exc:  # all: one a retry cannot fix (a token function that
                # gave no token too) ends the session with it, not this task unseen; one
                # that raised (TokenProviderError) is retried, as a lost connection
                if ws is not None:
                    await ws.close()
                if not _retryable(exc):
                    self._fail(exc)
                    return None
                cause = exc
                continue
            self.session.stats.reconnects += 1
            self._push(welcome)
            return ws
        return None

    async def _pinger(self) -> None:
        while not self._closing:
            await self._joined.wait()
            for k in range(4):  # a quick burst after each join: an estimate in ~0.3 s
                await self._ping()
                await asyncio.sleep(0.1 if k < 3 else 0.0)
            while self._joined.is_set() and not self._closing:
                await asyncio.sleep(self.ping_interval_s)
                await self._ping()

    async def _ping(self) -> None:
        if self._ws is not None:
            with contextlib.suppress(ConnectionClosed):
                await self._ws.send(encode(Ping(time.monotonic())))

    def _push(self, event: Event) -> None:
        if len(self._events) >= self._max_events:
            self._events.popleft()
            self.session.stats.events_dropped += 1
        self._events.append(event)
        self._wake.set()

    def _fail(self, cause: BaseException) -> None:
        log.info("session ended: %r", cause)
        self._failure = cause
        self._wake.set()


def _retryable(exc: BaseException) -> bool:
    """The session's rule, plus the WebSocket library's own failures (a refused
    handshake: 503 while a server starts, 429 when reconnecting too fast)."""
    return is_retryable(exc) or isinstance(exc, ConnectionClosed | InvalidHandshake)
