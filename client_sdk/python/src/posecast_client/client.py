"""The asyncio client: a thin shell that moves bytes between a WebSocket and the
pure :class:`~posecast_client.session.ClientSession`.

Lifecycle::

    connect ──> join ──> (send_frame | stream)* + events ──> close
                  │
                  └─ connection lost / SERVER_SHUTDOWN / TIMED_OUT / SLOW_CONSUMER:
                     Reconnecting(attempt, delay) ... back-off ... rejoin ──> Welcome

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
client: :meth:`Client.events` and :meth:`Client.send_frame` raise the typed error.

Three tasks run per client: the connection task (reads, decodes, reconnects), the
pinger (clock sync: four pings right after each join, then one every
``ping_interval_s``) and whatever the application runs itself.

**Protocol version.** The client offers ``posecast.v2`` then ``posecast.v1`` and
speaks what the server selects: against a v1-only server everything works as
before. On v2 the server sends each tick's poses in one message, rotations first
(keyframes and deltas against what this client holds); the session rebuilds each
avatar (positions by FK with its announced skeleton, world and local rotations) and
hands out the same :class:`~posecast_client.protocol.Pose` events, one per avatar.
``pose_rate_hz`` (60, 30, 20, 15) lowers how many a second it gets, and
``forecast_ms`` (0-100) asks for poses predicted that far ahead, to cancel this
client's network and render delay: each pose's ``t`` then stands that far past its
tick (whole ticks: 67 ms is 4 at 60 Hz), so the interpolator shows it that much sooner.
"""

from __future__ import annotations

import asyncio
import contextlib
import inspect
import logging
import random
import socket
import ssl
import time
from collections import deque
from collections.abc import (
    AsyncIterable,
    AsyncIterator,
    Awaitable,
    Callable,
    Generator,
    Iterable,
)
from types import TracebackType
from typing import Any
from urllib.parse import urlsplit

import numpy as np
from numpy.typing import ArrayLike
from websockets.asyncio.client import ClientConnection
from websockets.asyncio.client import connect as ws_connect
from websockets.exceptions import (
    ConnectionClosed,
    InvalidHandshake,
    InvalidStatus,
    InvalidURI,
    WebSocketException,
)
from websockets.typing import Subprotocol
from websockets.uri import parse_uri

from posecast_client.clock import ClockSync
from posecast_client.codec import decode, encode
from posecast_client.errors import (
    ClientClosedError,
    ConfigInvalidError,
    ConnectFailedError,
    ConnectionLostError,
    ProtocolError,
    TokenProviderError,
    VersionUnsupportedError,
)
from posecast_client.protocol import (
    ALL_VALID,
    MAX_FORECAST_MS,
    PROTOCOL_V2,
    SUBPROTOCOLS,
    Bye,
    Calibrate,
    Forecast,
    Layout,
    Message,
    Ping,
    PoseRate,
    Resync,
    Welcome,
)
from posecast_client.session import (
    ClientSession,
    Event,
    Reconnecting,
    Stats,
    backoff_delay,
    classify_join_reply,
    is_retryable,
)
from posecast_client.sites import tracker_set
from posecast_client.sources.base import TrackerSample

log = logging.getLogger("posecast_client")
Token = str | Callable[[], str | Awaitable[str]]
_TRANSPORT_ERRORS = (OSError, TimeoutError, ConnectionClosed, InvalidHandshake)


EXAMPLE_URL = "ws://127.0.0.1:8765/"
_TOKEN_HINT = (
    "pass the join token: a string your backend minted (mint_token(...) for a dev server), "
    "or a function returning one; an unset environment variable?"
)


def _what(value: object) -> str:
    """How an unusable argument is named in an error: ``None``, ``an empty string``..."""
    if value is None:
        return "None"
    if isinstance(value, str):
        return "an empty string" if not value else "a blank string"
    return f"a value of type {type(value).__name__}"


def check_url(url: object) -> str:
    """``url`` without leading or trailing whitespace (what the client stores and
    dials), if the client can dial it: ``ws://`` or ``wss://`` (any case), a host, a
    port from 1 to 65535 (absent: 80 or 443), no ``#fragment``.

    Raises:
        ConfigInvalidError: anything else, before any dialing, with a hint (for an
            ``http://`` URL its ``ws://`` twin; for ``host:port`` the ``ws://`` URL).
    """
    if not isinstance(url, str) or not url.strip():
        raise ConfigInvalidError(
            f"no server URL (got {_what(url)})",
            hint=f"pass the server's WebSocket URL, such as {EXAMPLE_URL}; an unset "
            "environment variable?",
        )
    text = url.strip()
    try:
        parts = urlsplit(text)
    except ValueError as exc:  # an unclosed [ of an IPv6 literal, say
        raise ConfigInvalidError(
            f"{url!r} is not a usable URL ({exc})", hint=f"such as {EXAMPLE_URL}"
        ) from exc
    scheme = parts.scheme.lower()
    slashes = text[len(scheme) + 1 :].startswith("//")
    if scheme in ("http", "https") and slashes:
        twin = ("ws" if scheme == "http" else "wss") + text[len(scheme) :]
        raise ConfigInvalidError(f"{url!r} is an HTTP URL, not a WebSocket one", hint=f"use {twin}")
    if scheme not in ("ws", "wss") or not slashes:
        hint = f"such as {EXAMPLE_URL}"
        if "://" not in text and scheme not in ("ws", "wss", "http", "https"):  # host:port
            hint = f"did you mean ws://{text}" + ("?" if "/" in text else "/?")
        raise ConfigInvalidError(
            f"{url!r} is not a WebSocket URL: it must start with ws:// (wss:// behind TLS)",
            hint=hint,
        )
    if not parts.hostname:
        raise ConfigInvalidError(f"{url!r} names no host", hint=f"such as {EXAMPLE_URL}")
    try:
        port = parts.port  # a property that checks the port
    except ValueError as exc:
        raise ConfigInvalidError(
            f"{url!r} has a bad port ({exc})", hint="a port is a number from 1 to 65535"
        ) from exc
    if port == 0:
        raise ConfigInvalidError(
            f"{url!r} has a bad port (0)", hint="a port is a number from 1 to 65535"
        )
    if parts.fragment or "#" in text:
        raise ConfigInvalidError(
            f"{url!r} has a #fragment, which a WebSocket URL may not",
            hint="leave out the # and what follows it",
        )
    try:
        parse_uri(text)  # what the WebSocket library itself takes, lest it refuse later
    except (InvalidURI, ValueError) as exc:
        raise ConfigInvalidError(
            f"{url!r} is not a usable URL ({exc})", hint=f"such as {EXAMPLE_URL}"
        ) from exc
    return text


def check_token(token: object) -> None:
    """A token the client can send: a non-blank string, or a callable (its result is
    checked at every join).

    Raises:
        ConfigInvalidError: ``None`` (an unset environment variable), an empty string,
            bytes or anything else.
    """
    if callable(token) or (isinstance(token, str) and token.strip()):
        return
    raise ConfigInvalidError(f"no token (got {_what(token)})", hint=_TOKEN_HINT)


_RUNNING = (
    "is a posecast server running there, and reachable from here? `posecast serve --dev` starts one"
)
_STATUS_HINTS = {
    429: "this address connected (or broke the protocol) too often: back off, try again later",
    503: "the server is starting, busy or full: try again in a moment, with back-off",
}


def connect_failure(url: str, exc: BaseException, open_timeout_s: float) -> ConnectFailedError:
    """The :class:`ConnectFailedError` for ``exc``, what opening ``url`` raised: the
    reason in words, a hint, and the HTTP status when the server refused the upgrade."""
    status: int | None = None
    secure = urlsplit(url).scheme.lower() == "wss"
    reason, hint = str(exc) or type(exc).__name__, _RUNNING
    if isinstance(exc, InvalidStatus):
        status = exc.response.status_code
        said = exc.response.body.decode("utf-8", "replace").strip() if exc.response.body else ""
        reason = f"the server refused the WebSocket upgrade with HTTP {status}"
        if said:
            reason += f" ({said.splitlines()[0][:120]})"
        hint = _STATUS_HINTS.get(
            status, f"is the URL a posecast WebSocket endpoint, such as {EXAMPLE_URL}?"
        )
    elif isinstance(exc, ConnectionRefusedError):
        reason = "connection refused (nothing listens at that port)"
    elif isinstance(exc, ssl.SSLCertVerificationError):
        reason = f"TLS: the server's certificate is not accepted ({exc.verify_message})"
        hint = "the certificate must be valid for the host and trusted here"
    elif isinstance(exc, ssl.SSLError) or (secure and isinstance(exc, ConnectionResetError)):
        reason = f"TLS failed ({getattr(exc, 'reason', None) or reason})"
        hint = "does the server speak TLS at that port? one without TLS takes ws://"
    elif isinstance(exc, socket.gaierror):
        reason = f"the host name {urlsplit(url).hostname!r} does not resolve ({exc.strerror})"
        hint = "check the host in the URL, and this machine's network"
    elif isinstance(exc, TimeoutError):
        reason = f"no WebSocket handshake within {open_timeout_s} s"
        hint = "is the host reachable from here (a firewall, a VPN)? open_timeout_s allows longer"
    elif isinstance(exc, InvalidHandshake):
        reason = f"the WebSocket handshake failed ({exc})"
        hint = f"is the URL a posecast WebSocket endpoint, such as {EXAMPLE_URL}?"
    failed = ConnectFailedError(url, reason, hint=hint, status=status)
    failed.__cause__ = exc
    return failed


def _retrieve(future: asyncio.Future[Any]) -> None:
    """Mark ``future``'s error as retrieved (see :meth:`Client.events`)."""
    if not future.cancelled():
        future.exception()


class Client:
    """One connection to a posecast server, kept alive across drops. Make it with
    :func:`connect`. Options (keyword-only, with their defaults):

    Args:
        url: the server's WebSocket URL, e.g. ``ws://127.0.0.1:8765/`` (leading and
            trailing whitespace dropped); or an iterable (list, tuple, generator) of
            URLs of one cluster, tried in order (failover): the first connection
            takes the first that opens, and each reconnect attempt moves on to the
            next URL after the one that was lost, wrapping around.
        token: the join token, or a callable returning one (called at every join, so
            a long session can fetch a fresh token before rejoining). A callable that
            raises gives :class:`~posecast_client.errors.TokenProviderError` (its
            error as ``__cause__``), retried on a rejoin like a lost connection; one
            that returns no token, :class:`ConfigInvalidError`, which ends the session.
        reconnect: rejoin after retryable losses (True).
        backoff_initial_s: the first reconnect delay (0.25 s), doubling per attempt...
        backoff_max_s: ...up to this (8 s).
        max_reconnect_attempts: give up after this many failed attempts in a row
            (``None``: never).
        ping_interval_s: seconds between clock-sync pings (2 s; 0 turns pings off).
        open_timeout_s: limit for the TCP + WebSocket handshake (5 s).
        join_timeout_s: limit for the ``welcome`` after ``hello`` (5 s).
        keepalive_s: WebSocket ping interval and timeout, to notice a dead link (5 s).
        max_events: events kept for :meth:`events` before the oldest are dropped (4096).
        seq0: ``seq`` of the first frame (0).
        protocol: the newest protocol version to offer (2: ``posecast.v2``, falling
            back to ``posecast.v1`` when the server only speaks v1; 1: v1 only).
    """

    def __init__(
        self,
        url: str | Iterable[str],
        token: Token,
        *,
        reconnect: bool = True,
        backoff_initial_s: float = 0.25,
        backoff_max_s: float = 8.0,
        max_reconnect_attempts: int | None = None,
        ping_interval_s: float = 2.0,
        open_timeout_s: float = 5.0,
        join_timeout_s: float = 5.0,
        keepalive_s: float = 5.0,
        max_events: int = 4096,
        seq0: int = 0,
        protocol: int = PROTOCOL_V2,
    ) -> None:
        several = isinstance(url, Iterable) and not isinstance(url, str | bytes | bytearray)
        urls = tuple(url) if several else (url,)  # a generator, a set... read once, here
        if not urls:
            raise ConfigInvalidError("no server URL", hint=f"pass one, such as {EXAMPLE_URL}")
        self.urls: tuple[str, ...] = tuple(check_url(u) for u in urls)
        check_token(token)
        self._url_index = 0
        self._token = token
        self.reconnect = reconnect
        self.backoff_initial_s, self.backoff_max_s = backoff_initial_s, backoff_max_s
        self.max_reconnect_attempts = max_reconnect_attempts
        self.ping_interval_s = ping_interval_s
        self.open_timeout_s, self.join_timeout_s = open_timeout_s, join_timeout_s
        self.keepalive_s = keepalive_s
        if protocol not in SUBPROTOCOLS:
            raise ValueError(f"protocol must be one of {sorted(SUBPROTOCOLS)}")
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
        offered = [
            SUBPROTOCOLS[v] for v in sorted(SUBPROTOCOLS, reverse=True) if v <= self.protocol
        ]
        try:
            ws = await ws_connect(
                self.url,
                subprotocols=[Subprotocol(p) for p in offered],
                compression=None,  # poses are quantised binary: deflate costs CPU for little
                open_timeout=self.open_timeout_s,
                ping_interval=self.keepalive_s or None,
                ping_timeout=self.keepalive_s or None,
                max_size=65_536,  # messages are at most 16384 bytes; the codec says TOO_LARGE
            )
        except (OSError, TimeoutError, WebSocketException) as exc:
            raise connect_failure(self.url, exc, self.open_timeout_s) from exc
        if ws.subprotocol not in offered:
            await ws.close()
            raise VersionUnsupportedError(f"the server selected none of {offered}")
        return ws

    @staticmethod
    def _version_of(ws: ClientConnection) -> int:
        return next(v for v, p in SUBPROTOCOLS.items() if p == ws.subprotocol)

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
                f"the token function returned {_what(token)}",
                hint="it must return the join token, a non-empty string",
            )
        version = self._version_of(ws)
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

    async def join(
        self,
        room: str,
        name: str,
        *,
        layout: str = Layout.HMD3_WAIST,
        rate_hz: float | None = None,
        watch: tuple[str, ...] = (),
        pose_rate_hz: float | None = None,
        forecast_ms: float | None = None,
    ) -> Welcome:
        """Join ``room`` as ``name`` (shown to others) and start receiving.

        Args:
            layout: the tracked points, which picks the server's model:
                :class:`Layout` ``HMD3_WAIST`` (``"hmd3+waist"``: head, both hands,
                waist) or ``HMD3`` (``"hmd3"``: headset and controllers only; the
                waist slot of frames is ignored), both served by default; or a
                tracker set (:mod:`posecast_client.sites`, such as
                ``"head,left_hand,right_hand,waist,left_foot,right_foot"``), served
                where the server runs the ``sites`` model: frames then carry one row
                per site, in the set's order.
            rate_hz: frames per second this client will send (absent: 60).
            watch: further rooms to watch (backend tokens only).
            pose_rate_hz: v2: poses per second to receive, 60 (absent), 30, 20 or 15
                (a phone, a spectator); ignored by a v1 server.
            forecast_ms: v2: poses predicted this many milliseconds ahead, 0 (absent)
                to 100, rounded by the server to whole ticks (``welcome.forecast_ms``
                says how far); ignored by a v1 server.

        Raises:
            ProtocolError: the typed refusal (``UnauthenticatedError``,
                ``ForbiddenError``, ``RoomFullError``...).
            ValueError: ``layout`` names no layout or tracker set, or ``forecast_ms``
                is outside 0-100 (nothing is sent).
        """
        tracker = tracker_set(layout)
        _check_forecast(forecast_ms or 0.0)
        if self._closing:
            raise ClientClosedError("the client is closed")
        if self._ws is None or self._hello_args is not None:
            raise RuntimeError("join() once per client, after `await connect(...)`")
        self._hello_args = {"room": room, "name": name, "layout": layout, "rate_hz": rate_hz,
                            "watch": watch, "pose_rate_hz": pose_rate_hz,
                            "forecast_ms": forecast_ms}  # fmt: skip
        if layout == Layout.HMD3_WAIST:
            self._hello_args["layout"] = None  # the default: canonical hellos leave it out
        self.session.tracker_set = tracker
        try:
            welcome = await self._handshake(self._ws)
        except BaseException:
            self._hello_args = None
            self.session.tracker_set = None
            raise
        self._joined.set()
        self._tasks = [asyncio.create_task(self._run(self._ws), name="posecast-client")]
        if self.ping_interval_s > 0:
            self._tasks.append(asyncio.create_task(self._pinger(), name="posecast-pinger"))
        return welcome

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

    # --- the application's side ------------------------------------------------------------

    def _check_usable(self) -> None:
        if self._failure is not None:
            raise self._failure
        if self._closing:
            raise ClientClosedError("the client is closed")
        if self._hello_args is None:
            raise RuntimeError("join() first")

    async def send(self, msg: Message) -> bool:
        """Send any client message (``calibrate``, ``selector``, ``kick``...).

        Returns False when it was dropped because the client is reconnecting.
        """
        self._check_usable()
        ws = self._ws
        if ws is None:
            return False
        try:
            await ws.send(encode(msg))
        except ConnectionClosed:
            return False  # the connection task notices and reconnects
        return True

    async def send_frame(
        self,
        positions: ArrayLike,
        orientations: ArrayLike,
        *,
        valid: int | None = None,
        seq: int | None = None,
        t: float | None = None,
    ) -> int | None:
        """Send one tracker frame; returns its ``seq``, or ``None`` if it was dropped
        because the client is reconnecting (its seq is used up all the same).

        Args:
            positions: ``(4, 3)`` world metres in slot order HEAD, LEFT_HAND,
                RIGHT_HAND, WAIST; for a tracker set ``(n, 3)``, one row per site in
                the set's order (an inertial site's world acceleration, m/s^2).
            orientations: ``(4, 4)`` (a set: ``(n, 4)``) world quaternions xyzw;
                normalised before sending.
            valid: bit ``i`` set means row ``i`` is tracked (default: all).
            seq: the frame counter (default: one more than the last, from ``seq0``);
                an explicit seq must be newer than the last one.
            t: the sample time on this client's ``time.monotonic()`` clock (default:
                now, or the last frame's time if that is later); it must not go
                backwards.

        Raises:
            OutOfRangeError, NotNormalisedError, OutOfOrderError, DuplicateError:
                the frame is unusable (nothing is sent).
            ProtocolError, ConnectionLostError: the session ended for good.
            ClientClosedError: after :meth:`close`.
        """
        self._check_usable()
        now = time.monotonic()
        if valid is None:
            ts = self.session.tracker_set
            valid = ALL_VALID if ts is None else ts.all_valid
        frame = self.session.frame(positions, orientations, now=now, valid=valid, seq=seq, t=t)
        if await self.send(frame):
            self.session.sent(frame, now)
            return frame.seq
        self.session.dropped(frame)
        return None

    async def stream(self, source: AsyncIterable[TrackerSample]) -> int:
        """Send every sample of ``source`` (a :class:`TrackerSource`) as it comes;
        returns how many frames were sent when the source ends."""
        sent = 0
        async for s in source:
            if await self.send_frame(s.positions, s.orientations, valid=s.valid, t=s.t) is not None:
                sent += 1
        return sent

    async def set_pose_rate(self, rate_hz: float) -> bool:
        """v2: receive ``rate_hz`` poses a second from now on (60, 30, 20 or 15).

        Raises:
            ValueError: another rate, or the server speaks only v1.
        """
        if rate_hz not in (60.0, 30.0, 20.0, 15.0):
            raise ValueError("the pose rate must be 60, 30, 20 or 15 Hz")
        if self.session.version < PROTOCOL_V2:
            raise ValueError("the server speaks posecast.v1: no pose rates")
        if self._hello_args is not None:
            self._hello_args["pose_rate_hz"] = rate_hz  # and after a reconnect
        return await self.send(PoseRate(float(rate_hz)))

    async def set_forecast(self, ms: float) -> bool:
        """v2: receive poses predicted ``ms`` (0-100) milliseconds ahead from now on
        (0: none); the server rounds it to whole ticks.

        Raises:
            ValueError: ``ms`` outside 0-100, or the server speaks only v1.
        """
        _check_forecast(ms)
        if self.session.version < PROTOCOL_V2:
            raise ValueError("the server speaks posecast.v1: no forecast")
        if self._hello_args is not None:
            self._hello_args["forecast_ms"] = ms  # and after a reconnect
        return await self.send(Forecast(float(ms)))

    async def resync(self) -> bool:
        """v2: ask for a keyframe of every avatar with the next poses (no-op on v1)."""
        if self.session.version < PROTOCOL_V2:
            return False
        return await self.send(Resync())

    async def calibrate(
        self, *, height_m: float | None = None, tpose: TrackerSample | None = None
    ) -> bool:
        """Calibrate the avatar by standing height (metres) or by a T-pose sample (the
        four trackers, or every site of the player's tracker set)."""
        if (height_m is None) == (tpose is None):
            raise ValueError("give height_m or tpose")
        if tpose is not None:
            q = np.asarray(tpose.orientations, dtype=np.float64)
            q = q / np.linalg.norm(q, axis=-1, keepdims=True)
            sites = self.session.tracker_set is not None
            return await self.send(
                Calibrate(positions=np.asarray(tpose.positions), orientations=q, sites=sites)
            )
        return await self.send(Calibrate(height_m=height_m))

    async def events(self, *, until: asyncio.Future[Any] | None = None) -> AsyncIterator[Event]:
        """Everything the server sends the application, in order: ``Pose``,
        ``Presence``, non-fatal ``Error`` messages, a ``Welcome`` after each rejoin,
        and ``Reconnecting`` while the connection is down.

        Ends after :meth:`close`, or once ``until`` (e.g. the task streaming frames) is
        done and the events so far are delivered; if ``until`` failed, with its error.
        ``until``'s error is this reader's to report: when the session ends first (a
        kick) and ``until`` then fails of the same cause, asyncio is not left to warn
        that nobody retrieved it. One reader at a time.

        Raises:
            ProtocolError: the error that ended the session (``KickedError``...).
            ConnectionLostError: the connection is gone and reconnecting gave up.
            Exception: the error ``until`` ended with.
        """
        if until is not None:
            until.add_done_callback(_retrieve)
        while True:
            while self._events:
                yield self._events.popleft()
            if self._failure is not None:
                raise self._failure
            if self._closing:
                return
            if until is not None and until.done():
                if not until.cancelled() and (error := until.exception()) is not None:
                    raise error
                return
            self._wake.clear()
            waiter = asyncio.ensure_future(self._wake.wait())
            try:
                await asyncio.wait([waiter] if until is None else [waiter, until],
                                   return_when=asyncio.FIRST_COMPLETED)  # fmt: skip
            finally:
                waiter.cancel()

    async def close(self, reason: str | None = None) -> None:
        """Say ``bye`` and close. The server then refuses this token for good (it
        guards against replays), so a closed client cannot rejoin with it."""
        if self._closing:
            return
        self._closing = True
        self._wake.set()
        ws, self._ws = self._ws, None
        if ws is not None:
            with contextlib.suppress(*_TRANSPORT_ERRORS):
                if self._hello_args is not None:
                    await ws.send(encode(Bye(reason)))
                await ws.close()
        for task in self._tasks:
            task.cancel()
        for task in self._tasks:
            with contextlib.suppress(asyncio.CancelledError):
                await task
        self._joined.clear()

    async def __aenter__(self) -> Client:
        return self

    async def __aexit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        await self.close()


def _retryable(exc: BaseException) -> bool:
    """The session's rule, plus the WebSocket library's own failures (a refused
    handshake: 503 while a server starts, 429 when reconnecting too fast)."""
    return is_retryable(exc) or isinstance(exc, ConnectionClosed | InvalidHandshake)


class Connecting:
    """What :func:`connect` returns: ``await`` it for a :class:`Client`, or use it as
    ``async with connect(...) as client:`` to close the client on the way out."""

    def __init__(self, client: Client) -> None:
        self._client = client

    async def _connect(self) -> Client:
        client = self._client
        for i in range(len(client.urls)):  # the first URL that opens
            client._url_index = i
            try:
                client._ws = await client._open()
            except ConnectFailedError:
                if i == len(client.urls) - 1:
                    raise
                continue
            break
        return client

    def __await__(self) -> Generator[Any, None, Client]:
        return self._connect().__await__()

    async def __aenter__(self) -> Client:
        return await self._connect()

    async def __aexit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        await self._client.close()


def connect(url: str | Iterable[str], token: Token, **options: Any) -> Connecting:
    """Open a WebSocket to a posecast server (``posecast.v2``, or ``posecast.v1`` when
    that is all the server speaks).

    ``await connect(url, token)`` gives a :class:`Client`; then :meth:`Client.join`.
    The token travels in ``hello``, never in the URL. ``options`` are the keyword
    options of :class:`Client` (reconnect, back-off, pings, timeouts). ``url`` may be
    an iterable (a list, a tuple...) of the URLs of one cluster's nodes: failover, see
    :class:`Client`.

    Raises:
        ConfigInvalidError: at once, before dialing: a URL that is not ``ws://`` or
            ``wss://`` with a host (``http://...``, ``host:port``), or no token (``None``
            from an unset environment variable, an empty string).
        ConnectFailedError: the server is unreachable (refused, a name that does not
            resolve, a timeout, TLS) or refused the WebSocket (``status`` 429 when
            connecting too often, 503 when it is not ready); with several URLs, the
            last one's once none opened. ``__cause__`` is the transport's exception. The
            first connection is never retried.
        VersionUnsupportedError: the server speaks neither protocol offered.
    """
    return Connecting(Client(url, token, **options))


def _check_forecast(ms: float) -> None:
    if not 0.0 <= ms <= MAX_FORECAST_MS:  # NaN fails too
        raise ValueError(f"forecast_ms must be within 0-{MAX_FORECAST_MS:g} ms, not {ms}")
