"""The viewer's HTTP routes (posecast.online.shell.http), called directly: no socket.

The page and its bundle are package data; ``/viewer/token`` mints spectator tokens
only for a ``dev`` server and a loopback client; the committed bundle is what the
build script makes from the TypeScript sources (checked in test_viewer.py, which has
Node).
"""

from __future__ import annotations

import gzip
import json
import time
from dataclasses import dataclass
from typing import Any

import pytest
from websockets.datastructures import Headers
from websockets.http11 import Request, Response

from posecast.online.auth.tokens import verify
from posecast.online.config import ServerConfig
from posecast.online.core.rooms import Rooms
from posecast.online.shell import http as viewer

SECRET = "viewer-test-secret-" + "x" * 16


@dataclass
class Peer:
    remote_address: Any


LOCAL = Peer(("127.0.0.1", 50000))
REMOTE = Peer(("203.0.113.7", 50000))


def get(
    path: str,
    *,
    dev: bool = True,
    peer: Peer = LOCAL,
    rooms: Rooms | None = None,
    headers: list[tuple[str, str]] | None = None,
) -> Response:
    assert viewer.handles(path.split("?", 1)[0])
    cfg = ServerConfig(token_secret=SECRET, dev=dev)
    registry = rooms if rooms is not None else Rooms(32, 64, 256)
    return viewer.respond(peer, Request(path, Headers(headers or [])), cfg, registry)


def test_only_viewer_paths_are_handled() -> None:
    assert viewer.handles("/viewer") and viewer.handles("/viewer/viewer.js")
    assert not viewer.handles("/viewers") and not viewer.handles("/metrics")


def test_bare_path_redirects_so_relative_urls_resolve() -> None:
    r = get("/viewer?room=demo")
    assert r.status_code == 302
    assert r.headers["Location"] == "viewer/?room=demo"
    assert get("/viewer").headers["Location"] == "viewer/"


def test_page_and_bundle_are_served_from_package_data() -> None:
    page = get("/viewer/?room=demo")
    assert page.status_code == 200
    assert page.headers["Content-Type"].startswith("text/html")
    assert "script-src 'self'" in page.headers["Content-Security-Policy"]
    assert page.headers["Referrer-Policy"] == "no-referrer"
    assert b'src="viewer.js"' in page.body
    js = get("/viewer/viewer.js")
    assert js.headers["Content-Type"].startswith("text/javascript")
    assert js.body.startswith(b"// posecast live viewer. Built by")
    assert int(js.headers["Content-Length"]) == len(js.body) > 100_000  # three.js is in it
    zipped = get("/viewer/viewer.js", headers=[("Accept-Encoding", "gzip, br")])
    assert zipped.headers["Content-Encoding"] == "gzip"
    assert gzip.decompress(zipped.body) == js.body
    assert get("/viewer/nope.js").status_code == 404


def test_a_repeated_accept_encoding_header_is_read_not_a_500() -> None:
    """Two ``Accept-Encoding`` lines (legal HTTP) raised ``MultipleValuesError`` in
    the route: HTTP 500 and an unthrottled ERROR traceback per request."""
    twice = [("Accept-Encoding", "br"), ("Accept-Encoding", "gzip")]
    r = get("/viewer/viewer.js", headers=twice)
    assert (r.status_code, r.headers["Content-Encoding"]) == (200, "gzip")
    plain = get("/viewer/", headers=[("Accept-Encoding", "br"), ("Accept-Encoding", "zstd")])
    assert plain.status_code == 200 and "Content-Encoding" not in plain.headers


def test_dev_server_mints_a_short_lived_spectator_token_for_loopback() -> None:
    r = get("/viewer/token?room=demo")
    assert r.status_code == 200
    assert r.headers["Cache-Control"] == "no-store"
    body = json.loads(r.body)
    claims = verify(SECRET.encode(), body["token"], now=time.time())
    assert (claims.role, claims.room, claims.player) == ("spectator", "demo", body["player"])
    assert claims.player.startswith("viewer-")
    assert claims.exp - claims.iat == viewer.VIEWER_TOKEN_TTL_S <= 300
    other = json.loads(get("/viewer/token?room=demo").body)
    assert other["player"] != body["player"]  # one id per page, no REPLACED between tabs


@pytest.mark.parametrize("room", ["two words", "x" * 65, "", "%00"])
def test_bad_rooms_get_no_token(room: str) -> None:
    assert get(f"/viewer/token?room={room}").status_code == 400


def test_no_dev_tokens_off_loopback_or_without_dev() -> None:
    assert get("/viewer/token?room=demo", peer=REMOTE).status_code == 403
    assert get("/viewer/rooms", peer=REMOTE).status_code == 403
    for path in ("/viewer/token?room=demo", "/viewer/rooms"):
        r = get(path, dev=False)
        assert r.status_code == 404 and b"token" not in r.body
    assert get("/viewer/", dev=False).status_code == 200  # the page itself is public


def test_dev_room_list() -> None:
    rooms = Rooms(32, 64, 256)
    rooms.add_player("demo", "alice", "Alice")
    rooms.add_player("demo", "bob", "Bob")
    rooms.add_watcher(("lobby",), "cam")
    listing = json.loads(get("/viewer/rooms", rooms=rooms).body)
    assert listing == [{"room": "demo", "players": 2}, {"room": "lobby", "players": 0}]


# --- the upgrade gate ------------------------------------------------------------------


class GatePeer:
    """A connection as :class:`~posecast.online.shell.http.HttpRoutes` sees it."""

    def __init__(self, ip: str) -> None:
        self.remote_address = (ip, 50000)

    def respond(self, status: int, text: str) -> Response:
        return Response(status, "", Headers(), text.encode())


def _gate(**cfg: Any) -> tuple[viewer.HttpRoutes, Any, list[float]]:
    from posecast.online.cluster.memory import MemoryBus
    from posecast.online.core.hub import Hub
    from posecast.online.metrics import Metrics

    config = ServerConfig(token_secret=SECRET, **cfg)
    metrics, clock = Metrics(), [0.0]
    hub = Hub(config, metrics)
    routes = viewer.HttpRoutes(
        config, metrics, hub, MemoryBus(clock=lambda: clock[0]),
        ready=lambda: True, open_connections=lambda: 0, clock=lambda: clock[0],
    )  # fmt: skip
    return routes, hub, clock


def _upgrade(routes: viewer.HttpRoutes, ip: str) -> int | None:
    answer = routes(GatePeer(ip), Request("/", Headers()))
    return None if answer is None else answer.status_code


def test_the_gate_refuses_an_address_whose_fatal_budget_is_spent_with_429() -> None:
    routes, hub, clock = _gate(fatal_per_ip_per_min=2)
    for _ in range(2):
        hub.admission.fatal.charge("10.0.0.5", clock[0])
    assert _upgrade(routes, "10.0.0.5") == 429
    assert _upgrade(routes, "10.0.0.6") is None  # another address goes on to the handshake
    assert routes.metrics.value("posecast_connects_total", {"result": "fatal_budget"}) == 1
    clock[0] = 31.0  # 2 a minute: one back after 30 s
    assert _upgrade(routes, "10.0.0.5") is None


def test_the_gate_caps_new_connections_node_wide_with_503() -> None:
    routes, _, _ = _gate(accepts_per_s=3.0)
    answers = [_upgrade(routes, f"10.0.1.{i}") for i in range(5)]  # five addresses at once
    assert answers == [None, None, None, 503, 503]
    assert routes.metrics.value("posecast_connects_total", {"result": "busy"}) == 2
