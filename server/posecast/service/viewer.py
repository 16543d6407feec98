"""The live viewer, served over plain HTTP on the server's own port.

Routes (GET, answered from ``process_request`` before any WebSocket handshake):

==========================  ============================================================
``/viewer``                 302 to ``viewer/`` (query kept), so the page's relative URLs
                            resolve the same behind a path prefix
``/viewer/``                the page (``posecast/viewer/index.html``)
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
import secrets
import time
from functools import cache
from http import HTTPStatus
from importlib import resources
from typing import Any, Protocol
from urllib.parse import parse_qs, urlsplit

from websockets.datastructures import Headers
from websockets.http11 import Request, Response

from posecast.auth.tokens import mint
from posecast.protocol.fields import ID_PATTERN
from posecast.service.config import ServerConfig
from posecast.service.rooms import Rooms

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
    """The one thing asked of the connection (a websockets ``ServerConnection``)."""

    @property
    def remote_address(self) -> Any: ...


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
        if "gzip" in request.headers.get("Accept-Encoding", ""):
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
    return (resources.files("posecast") / "viewer" / name).read_bytes()


@cache
def _asset_gzip(name: str) -> bytes:
    return gzip.compress(_asset(name), compresslevel=9, mtime=0)


def _is_loopback(connection: Peer) -> bool:
    addr = connection.remote_address
    try:
        return addr is not None and ipaddress.ip_address(str(addr[0])).is_loopback
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
