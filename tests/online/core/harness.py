"""A hub driven without sockets, for the core's tests: join, send, read an outbox."""

from __future__ import annotations

import time
from typing import Any

from posecast.online.core.hub import Hub
from posecast.online.metrics import Metrics
from posecast.online.protocol import decode, encode
from posecast.online.protocol.messages import (
    Error,
    Hello,
    Message,
)
from tests.online.conftest import make_cfg, token


class Harness:
    def __init__(self, **cfg: Any) -> None:
        self.hub = Hub(make_cfg(**cfg), Metrics())
        self.now = time.time()
        self.versions: dict[int, int] = {}  # conn -> its protocol version

    def join(
        self, player: str, room: str = "r1", role: str = "player", version: int = 1, **kw: Any
    ) -> int:
        conn = self.hub.connect("10.0.0.1", self.now, version)
        self.versions[conn] = version
        tok = kw.pop("tok", None) or token(room=room, player=player, role=role, **kw)
        watch = tuple(kw.get("rooms", ())) if role == "backend" else ()
        self.send(conn, Hello(version, tok, room, player.upper(), watch=watch))
        return conn

    def send(self, conn: int, msg: Message) -> None:
        self.hub.receive(conn, encode(msg), self.now)

    def inbox(self, conn: int) -> list[Message]:
        box = self.hub.outbox(conn)
        assert box is not None
        out = [decode(d, version=self.versions.get(conn, 1)) for d in box.take()]
        box.sent(self.now)
        return out

    def codes(self, conn: int) -> list[str]:
        return [m.code for m in self.inbox(conn) if isinstance(m, Error)]
