"""The asyncio client, what an application calls: connect, join, send frames, read
events, close. With :mod:`posecast_client.link` it is a thin shell that moves bytes
between a WebSocket and the pure :class:`~posecast_client.session.ClientSession`.

Lifecycle::

    connect ──> join ──> (send_frame | stream)* + events ──> close
                  │
                  └─ connection lost / SERVER_SHUTDOWN / TIMED_OUT / SLOW_CONSUMER:
                     Reconnecting(attempt, delay) ... back-off ... rejoin ──> Welcome

Retryable losses (a dropped socket, ``SERVER_SHUTDOWN``, ``TIMED_OUT``...) are
rejoined after a back-off, each attempt on the next of several URLs; errors a retry
cannot fix end the client with the typed error. The connection behind a client,
its reconnect loop and its tasks are :mod:`posecast_client.link`'s; opening one
WebSocket, and the checks before it, :mod:`posecast_client.dial`'s.

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
import time
from collections.abc import AsyncIterable, AsyncIterator, Generator, Iterable
from types import TracebackType
from typing import Any

import numpy as np
from numpy.typing import ArrayLike
from websockets.exceptions import ConnectionClosed, InvalidHandshake

from posecast_client.codec import encode
from posecast_client.dial import EXAMPLE_URL, check_token, check_url, connect_failure
from posecast_client.errors import ClientClosedError, ConfigInvalidError
from posecast_client.link import Link, Token, log
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
    PoseRate,
    Resync,
    Welcome,
)
from posecast_client.session import Event
from posecast_client.sites import tracker_set
from posecast_client.sources.base import TrackerSample

__all__ = [
    "EXAMPLE_URL",
    "Client",
    "Connecting",
    "Token",
    "check_token",
    "check_url",
    "connect",
    "connect_failure",
    "log",
]
_TRANSPORT_ERRORS = (OSError, TimeoutError, ConnectionClosed, InvalidHandshake)


def _retrieve(future: asyncio.Future[Any]) -> None:
    """Mark ``future``'s error as retrieved (see :meth:`Client.events`)."""
    if not future.cancelled():
        future.exception()


class Client(Link):
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
        urls = tuple(check_url(u) for u in urls)
        check_token(token)
        if protocol not in SUBPROTOCOLS:
            raise ValueError(f"protocol must be one of {sorted(SUBPROTOCOLS)}")
        super().__init__(
            urls,
            token,
            reconnect=reconnect,
            backoff_initial_s=backoff_initial_s,
            backoff_max_s=backoff_max_s,
            max_reconnect_attempts=max_reconnect_attempts,
            ping_interval_s=ping_interval_s,
            open_timeout_s=open_timeout_s,
            join_timeout_s=join_timeout_s,
            keepalive_s=keepalive_s,
            max_events=max_events,
            seq0=seq0,
            protocol=protocol,
        )

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
        self._start(self._ws)
        return welcome

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


class Connecting:
    """What :func:`connect` returns: ``await`` it for a :class:`Client`, or use it as
    ``async with connect(...) as client:`` to close the client on the way out."""

    def __init__(self, client: Client) -> None:
        self._client = client

    async def _connect(self) -> Client:
        client = self._client
        await client._open_first()  # the first URL that opens
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
