"""Dialing one server: what may be dialed, the WebSocket opened, and why it failed.

Before any dialing, :func:`check_url` and :func:`check_token` refuse what the client
cannot use (``ConfigInvalidError`` with a hint: an ``http://`` URL, ``host:port``, an
unset environment variable). :func:`open_websocket` opens one connection, offering
``posecast.v2`` then ``posecast.v1``; when it fails, :func:`connect_failure` says why
in words (refused, a name that does not resolve, TLS, a timeout, an HTTP status) as
a :class:`~posecast_client.errors.ConnectFailedError`. The joining, reading and
reconnecting are :mod:`posecast_client.link`'s.
"""

from __future__ import annotations

import socket
import ssl
from urllib.parse import urlsplit

from websockets.asyncio.client import ClientConnection
from websockets.asyncio.client import connect as ws_connect
from websockets.exceptions import (
    InvalidHandshake,
    InvalidStatus,
    InvalidURI,
    WebSocketException,
)
from websockets.typing import Subprotocol
from websockets.uri import parse_uri

from posecast_client.errors import (
    ConfigInvalidError,
    ConnectFailedError,
    VersionUnsupportedError,
)
from posecast_client.protocol import SUBPROTOCOLS

EXAMPLE_URL = "ws://127.0.0.1:8765/"
_TOKEN_HINT = (
    "pass the join token: a string your backend minted (mint_token(...) for a dev server), "
    "or a function returning one; an unset environment variable?"
)


def describe_argument(value: object) -> str:
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
            f"no server URL (got {describe_argument(url)})",
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
    raise ConfigInvalidError(f"no token (got {describe_argument(token)})", hint=_TOKEN_HINT)


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


async def open_websocket(
    url: str, *, protocol: int, open_timeout_s: float, keepalive_s: float
) -> ClientConnection:
    """Open a WebSocket to ``url`` offering the protocol versions up to ``protocol``,
    newest first (the limits are :class:`~posecast_client.client.Client`'s options).

    Raises:
        ConnectFailedError: the transport or the handshake failed (see
            :func:`connect_failure`), its exception as ``__cause__``.
        VersionUnsupportedError: the server selected none of the versions offered.
    """
    offered = [SUBPROTOCOLS[v] for v in sorted(SUBPROTOCOLS, reverse=True) if v <= protocol]
    try:
        ws = await ws_connect(
            url,
            subprotocols=[Subprotocol(p) for p in offered],
            compression=None,  # poses are quantised binary: deflate costs CPU for little
            open_timeout=open_timeout_s,
            ping_interval=keepalive_s or None,
            ping_timeout=keepalive_s or None,
            max_size=65_536,  # messages are at most 16384 bytes; the codec says TOO_LARGE
        )
    except (OSError, TimeoutError, WebSocketException) as exc:
        raise connect_failure(url, exc, open_timeout_s) from exc
    if ws.subprotocol not in offered:
        await ws.close()
        raise VersionUnsupportedError(f"the server selected none of {offered}")
    return ws


def version_of(ws: ClientConnection) -> int:
    """The protocol version (1 or 2) that the server selected on ``ws``."""
    return next(v for v, p in SUBPROTOCOLS.items() if p == ws.subprotocol)
