"""What each HTTP endpoint of the server's one port tells a caller without a token.

The routes (``online/shell/http.py``): ``/healthz``, ``/readyz``,
``/metrics``, the viewer page and script under ``/viewer/``, and, with ``--dev`` only
and from loopback only, ``/viewer/token`` and ``/viewer/rooms``. Everything else is a
WebSocket handshake, which sends nothing before a ``hello`` with a valid token.

A room with recognisable names is open and streaming while every route (and some
that do not exist) is fetched: no body, and no ``/metrics`` label, may name the room,
its player or its display name, and a WebSocket that sends no ``hello`` gets no data
of any room (only TIMED_OUT).
"""

from __future__ import annotations

from collections.abc import Iterator

import pytest
from prometheus_client.parser import text_string_to_metric_families

from posecast.online.protocol.messages import Error, Pose, Welcome
from tests.online.conftest import make_cfg, token
from tests.system.reliability.arena import Arena, http_get
from tests.system.reliability.hostile_helpers import OTHER_IP, Attacker

pytestmark = pytest.mark.timeout(120)
ROOM, PLAYER, NAME = "zq-secret-room", "zq-secret-player", "ZqSecretName"
SECRETS = (ROOM, PLAYER, NAME)
PATHS = (
    "/", "/healthz", "/readyz", "/metrics", "/viewer", "/viewer/", "/viewer/viewer.js",
    "/viewer/token", f"/viewer/token?room={ROOM}", "/viewer/rooms", "/rooms", "/token",
    "/viewer/../metrics", "/viewer/%2e%2e/rooms", "/metrics?room=" + ROOM, "/admin",
    f"/{ROOM}", "/viewer/index.html",
)  # fmt: skip
# The labels /metrics may carry: none of them names a room or a player. A new label
# fails this test on purpose: decide (and document) before exporting per-room data.
# posecast_engine_info's (layout, backend, isa, precision) name the node's engines.
METRIC_LABELS = {"role", "result", "code", "reason", "direction", "kind", "le"}
METRIC_LABELS |= {"layout", "backend", "isa", "precision"}


@pytest.fixture(scope="module", params=[False, True], ids=["prod", "dev"])
def arena(request: pytest.FixtureRequest) -> Iterator[Arena]:
    with Arena(make_cfg(lookahead=1, dev=request.param, hello_timeout_s=1.0)) as a:
        secret = Attacker(a.port)
        assert isinstance(secret.hello(token(ROOM, PLAYER), room=ROOM, name=NAME), Welcome)
        for seq in range(30):
            secret.ws.send(secret_frame(seq))
        yield a
        secret.close()


def secret_frame(seq: int) -> bytes:
    from posecast.online.protocol import encode
    from tests.online.conftest import walk_frame

    return encode(walk_frame(seq, seed=7))


def _words(text: str) -> set[str]:
    import re

    return set(re.findall(r"[A-Za-z0-9_.:-]+", text))


def test_no_route_names_a_room_or_player(arena: Arena) -> None:
    dev = arena.cfg.dev
    seen = {}
    for path in PATHS:
        for source in ("127.0.0.1", OTHER_IP):
            status, _, body = http_get(arena.port, path, source_ip=source)
            seen[path, source] = status
            text = body.decode("utf-8", "replace")
            if dev and path.startswith("/viewer/rooms"):
                # Deliberate, documented (online/shell/http.py): with --dev, loopback callers
                # may list this node's rooms and mint spectator tokens.
                assert ROOM in text and status == 200
                continue
            if dev and path.startswith("/viewer/token"):
                assert status == 200 and PLAYER not in text
                continue
            if path == "/viewer/viewer.js":
                assert status == 200  # the static bundle; it holds no server data
                continue
            assert not _words(text) & set(SECRETS), (path, source, status, text[:200])
    if not dev:
        for sub in ("token", "rooms"):
            assert seen[f"/viewer/{sub}", "127.0.0.1"] == 404  # as if they did not exist
        assert seen["/metrics", OTHER_IP] == 200  # the same port: see docs/reliability.md
    for path in ("/rooms", "/token", "/admin", f"/{ROOM}"):
        assert seen[path, "127.0.0.1"] >= 400


def test_metrics_carry_no_room_or_player_labels(arena: Arena) -> None:
    status, _, body = http_get(arena.port, "/metrics")
    assert status == 200
    labels: dict[str, set[str]] = {}
    for fam in text_string_to_metric_families(body.decode()):
        for s in fam.samples:
            for k, v in s.labels.items():
                labels.setdefault(k, set()).add(v)
    assert set(labels) <= METRIC_LABELS, set(labels) - METRIC_LABELS
    values = set().union(*labels.values())
    assert not values & set(SECRETS)
    assert "player" in labels["role"]  # the scrape did see the players, by role only


def test_a_websocket_without_hello_gets_no_room_data(arena: Arena) -> None:
    """Connect and wait past the hello timeout: the only message is TIMED_OUT."""
    att = Attacker(arena.port, source_ip=OTHER_IP)
    err = att.next(lambda m: True, timeout_s=5)
    assert isinstance(err, Error) and (err.code, err.fatal) == ("TIMED_OUT", True)
    assert not [m for m in att.received if isinstance(m, Pose | Welcome)]
    assert att.received == [err]
    att.close()
