"""Admission (posecast.online.core.admission): the one error path for a message, and
the fatal-error budget that turns a repeat offender away."""

from __future__ import annotations

import logging
import time

import pytest

from posecast.online.core.hub import Hub
from posecast.online.core.session import Session
from posecast.online.metrics import Metrics
from posecast.online.protocol import decode, encode
from posecast.online.protocol.messages import Error, Hello, Message, Ping, Pong
from tests.online.conftest import make_cfg, token

IP = "10.0.0.9"


def _inbox(hub: Hub, conn: int) -> list[Message]:
    box = hub.outbox(conn)
    assert box is not None
    out = [decode(d) for d in box.take()]
    box.sent(0.0)
    return out


def _joined(hub: Hub, player: str, now: float) -> int:
    conn = hub.connect(IP, now)
    hub.receive(conn, encode(Hello(1, token(player=player), "r1", player)), now)
    _inbox(hub, conn)
    return conn


def test_a_bug_in_a_handler_is_logged_answered_internal_and_the_session_goes_on(
    monkeypatch: pytest.MonkeyPatch, caplog: pytest.LogCaptureFixture
) -> None:
    hub, now = Hub(make_cfg(), Metrics()), time.time()
    conn = _joined(hub, "p", now)
    real = Session.handle

    def broken(self: Session, msg: Message, t: float) -> object:
        if isinstance(msg, Ping) and msg.t0 == 1.0:
            raise RuntimeError("a bug")
        return real(self, msg, t)

    monkeypatch.setattr(Session, "handle", broken)
    with caplog.at_level(logging.ERROR, logger="posecast.core"):
        hub.receive(conn, encode(Ping(1.0)), now)
    (err,) = _inbox(hub, conn)
    assert isinstance(err, Error) and (err.code, err.fatal) == ("INTERNAL", False)
    assert any(r.exc_info and "a bug" in str(r.exc_info[1]) for r in caplog.records)
    assert hub.metrics.value("posecast_errors_total", {"code": "INTERNAL"}) == 1
    hub.receive(conn, encode(Ping(2.0)), now)  # the connection is still served
    assert [type(m) for m in _inbox(hub, conn)] == [Pong]


def test_fatal_errors_spend_the_addresss_budget_and_then_it_is_turned_away() -> None:
    hub, now = Hub(make_cfg(fatal_per_ip_per_min=3), Metrics()), time.time()
    for _ in range(3):
        assert hub.admits(IP, now)
        conn = _joined(hub, "p", now)
        hub.receive(conn, b"\xc1", now)  # MALFORMED: fatal
        assert [m.code for m in _inbox(hub, conn) if isinstance(m, Error)] == ["MALFORMED"]
        hub.disconnect(conn, now)
    assert not hub.admits(IP, now)
    assert hub.admits("10.0.0.10", now)
    assert hub.admits(IP, now + 21.0)  # 3 a minute: one back after 20 s


def test_being_replaced_or_kicked_does_not_spend_the_budget() -> None:
    hub, now = Hub(make_cfg(fatal_per_ip_per_min=1), Metrics()), time.time()
    for _ in range(3):  # each join replaces the one before (REPLACED, fatal)
        _joined(hub, "p", now)
    assert hub.admits(IP, now)
