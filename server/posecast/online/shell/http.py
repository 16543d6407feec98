"""Plain HTTP on the server's own port, answered before any WebSocket handshake.

:class:`HttpRoutes` is websockets' ``process_request``: every request reaches it
first. Health and metrics, the live viewer, and the gate every WebSocket upgrade
passes, cheapest check first, so that a refused connection costs almost nothing
(no handshake, no token check, no join):

==========================  ============================================================
``/healthz``                200 while the process is up
``/readyz``                 200 once the engine is loaded and, with ``--redis``, the bus
                            is up; 503 while starting, shutting down or cut off
``/metrics``                Prometheus text (:mod:`posecast.online.metrics`)
any other path              the WebSocket upgrade: 503 until ready; 429 past the
                            per-IP attempt rate (``conn_per_ip_per_min``) or once the
                            IP's fatal-error budget is spent (``fatal_per_ip_per_min``);
                            503 past the node-wide accept rate (``accepts_per_s``) or
                            ``max_connections``; otherwise the handshake goes on
==========================  ============================================================

The viewer's routes (the page itself is built from ``client_sdk/typescript/viewer``
into ``static/``):

==========================  ============================================================
``/viewer``                 302 to ``viewer/`` (query kept), so the page's relative URLs
                            resolve the same behind a path prefix
``/viewer/``                the page (``posecast/online/shell/static/index.html``)
``/viewer/viewer.js``       the app: three.js and the TypeScript SDK in one file, built
                            by ``client_sdk/typescript/scripts/build-viewer.mjs``
``/viewer/token?room=R``    dev only: a short-lived spectator token for room ``R``
``/viewer/rooms``           dev only: this node's open rooms and their player counts
==========================  ============================================================

The page joins a room as a **spectator** and needs a token for it. In production it
reads one from its URL, ``/viewer/?room=R#token=T`` (the fragment never reaches the
server, so no access log or proxy sees it; ``?token=`` works too, and the page drops
it from the address bar). Minting stays with the game backend, which holds the
secret, as for every other client.

With ``--dev`` the page asks ``/viewer/token`` instead, and asks again on every
reconnect. That endpoint mints a spectator token for any room, so anyone who can
reach it can watch every room: it answers only when the server runs with ``dev`` on
AND the request comes from a loopback address, and the token lives
``VIEWER_TOKEN_TTL_S`` seconds (enough for the ``hello``; a spectator token lets its
holder watch, never send frames, select or kick). Behind a reverse proxy on the same
machine every request looks like loopback, so never put a ``--dev`` server behind
one. Without ``dev`` both dev routes answer 404, as if they did not exist.
"""

from __future__ import annotations

import gzip
import ipaddress
import json
import logging
import secrets
import time
from collections.abc import Callable
from functools import cache
from http import HTTPStatus
from importlib import resources
from typing import Any, Protocol
from urllib.parse import parse_qs, urlsplit

from websockets.datastructures import Headers
from websockets.http11 import Request, Response

from posecast.online.auth.tokens import mint
from posecast.online.cluster.bus import Bus
from posecast.online.config import ServerConfig
from posecast.online.core.hub import Hub
from posecast.online.core.ratelimit import IpLimiter, TokenBucket
from posecast.online.core.rooms import Rooms
from posecast.online.metrics import CONTENT_TYPE, Metrics
from posecast.online.protocol.fields import ID_PATTERN

log = logging.getLogger("posecast.http")

PREFIX = "/viewer"
VIEWER_TOKEN_TTL_S = 120
MAX_ROOM_BYTES = 64  # the v1 maximum of max_room_bytes
_ASSETS = {  # path under /viewer/ -> (package file, content type)
    "": ("index.html", "text/html; charset=utf-8"),
    "viewer.js": ("viewer.js", "text/javascript; charset=utf-8"),
}
_PAGE_CSP = (
    "default-src 'self'; script-src 'self'; style-src 'self' 'unsafe-inline'; "
    "connect-src 'self'; img-src 'self' data:; base-uri 'none'; frame-ancestors 'none'"
)


class Peer(Protocol):
    """What is asked of the connection (a websockets ``ServerConnection``)."""

    @property
    def remote_address(self) -> Any: ...

    def respond(self, status: int, text: str) -> Response: ...


class HttpRoutes:
    """``process_request`` for one server: answers HTTP, or lets an upgrade through."""

    def __init__(
        self,
        cfg: ServerConfig,
        metrics: Metrics,
        hub: Hub,
        bus: Bus,
        *,
        ready: Callable[[], bool],
        open_connections: Callable[[], int],
        clock: Callable[[], float],
    ) -> None:
        self.cfg, self.metrics, self.hub, self.bus = cfg, metrics, hub, bus
        self._ready, self._open, self._clock = ready, open_connections, clock
        self.per_ip = IpLimiter(cfg.conn_per_ip_per_min)
        self.accepts = TokenBucket(cfg.accepts_per_s, cfg.accepts_per_s)

    def __call__(self, connection: Peer, request: Request) -> Response | None:
        path = request.path.split("?", 1)[0]
        if path == "/healthz":
            return connection.respond(200, "ok\n")
        if path == "/readyz":
            if self._ready() and not self.bus.healthy:
                # The reason stays in the logs: its text may name internal hosts.
                return connection.respond(503, "not ready: redis unavailable\n")
            return connection.respond(200, "ready\n") if self._ready() else _unavailable(connection)
        if path == "/metrics":
            body = self.metrics.render()
            headers = Headers([("Content-Type", CONTENT_TYPE), ("Content-Length", str(len(body)))])
            return Response(200, "OK", headers, body)
        if handles(path):
            return respond(connection, request, self.cfg, self.hub.rooms)
        return self._upgrade(connection)

    def _upgrade(self, connection: Peer) -> Response | None:
        refused = self.metrics.connects
        if not self._ready():
            refused.labels("unavailable").inc()
            return _unavailable(connection)
        ip, now = peer_ip(connection), self._clock()
        if not self.per_ip.allow(ip, now):
            refused.labels("rate_limited").inc()
            log.info("connection refused", extra={"ip": ip, "reason": "per-IP rate"})
            return connection.respond(429, "too many connection attempts\n")
        if not self.hub.admits(ip, now):
            refused.labels("fatal_budget").inc()
            return connection.respond(429, "too many protocol errors from this address\n")
        if not self.accepts.allow(now):
            refused.labels("busy").inc()
            return connection.respond(503, "busy: too many new connections\n")
        if self._open() >= self.cfg.max_connections:
            refused.labels("full").inc()
            return _unavailable(connection)
        refused.labels("accepted").inc()
        return None  # go on with the WebSocket handshake


def peer_ip(connection: Peer) -> str:
    addr = connection.remote_address
    return str(addr[0]) if addr else "?"


def _unavailable(connection: Peer) -> Response:
    return connection.respond(503, "not ready\n")


def handles(path: str) -> bool:
    """Whether ``path`` (without the query) is one of the viewer's routes."""
    return path == PREFIX or path.startswith(PREFIX + "/")


def respond(connection: Peer, request: Request, cfg: ServerConfig, rooms: Rooms) -> Response:
    """The answer to a GET of a viewer route (``handles(path)`` is true)."""
    url = urlsplit(request.path)
    if url.path == PREFIX:
        location = "viewer/" + (f"?{url.query}" if url.query else "")
        return _response(302, b"", "text/plain", [("Location", location)])
    sub = url.path[len(PREFIX) + 1 :]
    if sub in _ASSETS:
        name, content_type = _ASSETS[sub]
        extra = [("Content-Security-Policy", _PAGE_CSP)] if name.endswith(".html") else []
        # get_all: a repeated header is legal HTTP, and get() raises on it (HTTP 500).
        if "gzip" in ",".join(request.headers.get_all("Accept-Encoding")):
            body, extra = _asset_gzip(name), [*extra, ("Content-Encoding", "gzip")]
        else:
            body = _asset(name)
        return _response(200, body, content_type, [*extra, ("Cache-Control", "no-cache")])
    if sub in ("token", "rooms") and cfg.dev:
        if not _is_loopback(connection):
            return _text(403, "viewer tokens are handed to loopback clients only\n")
        if sub == "rooms":
            open_rooms = sorted(rooms.rooms.items())
            return _json([{"room": name, "players": len(r.players)} for name, r in open_rooms])
        room = parse_qs(url.query, keep_blank_values=True).get("room", ["demo"])[0]
        if len(room.encode()) > MAX_ROOM_BYTES or ID_PATTERN.fullmatch(room) is None:
            return _text(400, "room must be 1 to 64 bytes of A-Z a-z 0-9 _ . : -\n")
        player = f"viewer-{secrets.token_hex(4)}"
        token = mint(
            cfg.secret_bytes,
            room=room,
            player=player,
            role="spectator",
            ttl_s=VIEWER_TOKEN_TTL_S,
            now=time.time(),
        )
        return _json({"token": token, "room": room, "player": player, "ttl_s": VIEWER_TOKEN_TTL_S})
    return _text(404, "not found\n")


@cache
def _asset(name: str) -> bytes:
    return (resources.files("posecast.online.shell") / "static" / name).read_bytes()


@cache
def _asset_gzip(name: str) -> bytes:
    return gzip.compress(_asset(name), compresslevel=9, mtime=0)


def _is_loopback(connection: Peer) -> bool:
    addr = connection.remote_address
    return addr is not None and is_loopback_address(str(addr[0]))


def is_loopback_address(host: str) -> bool:
    """Whether ``host`` is a loopback IP address (what the dev-only routes serve)."""
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:
        return False


def _response(
    status: int, body: bytes, content_type: str, extra: list[tuple[str, str]]
) -> Response:
    headers = Headers(
        [
            ("Content-Type", content_type),
            ("Content-Length", str(len(body))),
            ("X-Content-Type-Options", "nosniff"),
            ("Referrer-Policy", "no-referrer"),
            *extra,
        ]
    )
    return Response(status, HTTPStatus(status).phrase, headers, body)


def _text(status: int, text: str) -> Response:
    return _response(status, text.encode(), "text/plain; charset=utf-8", [])


def _json(value: object) -> Response:
    body = json.dumps(value, separators=(",", ":")).encode()
    return _response(200, body, "application/json", [("Cache-Control", "no-store")])
