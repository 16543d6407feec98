"""Admission (posecast.online.core.admission): joins, takeovers, kicks, refusals,
timeouts and shutdown; the one error path for a message; the fatal-error budget."""

from __future__ import annotations

import logging
import time

import pytest

from posecast.errors import TooLargeError
from posecast.online.core.hub import Hub
from posecast.online.core.session import Phase, Session
from posecast.online.core.tick import EngineOpKind
from posecast.online.metrics import Metrics
from posecast.online.protocol import decode, encode
from posecast.online.protocol.messages import (
    Bye,
    Error,
    Hello,
    Kick,
    Message,
    Ping,
    Pong,
    Presence,
    Welcome,
)
from tests.online.conftest import make_cfg, token, walk_frame
from tests.online.core.harness import Harness

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


def test_reconnect_with_the_same_player_takes_over_silently() -> None:
    h = Harness()
    a1, b = h.join("a"), h.join("b")
    h.inbox(a1), h.inbox(b)
    h.hub.take_tick_input()
    a2 = h.join("a")
    assert h.codes(a1) == ["REPLACED"] and h.hub.outbox(a1).closed  # type: ignore[union-attr]
    assert isinstance(h.inbox(a2)[0], Welcome)
    assert h.inbox(b) == []  # no leave/join for a takeover
    assert h.hub.take_tick_input().ops == []  # the engine keeps the player
    h.hub.disconnect(a1, h.now)  # the old socket goes away later
    assert h.hub.rooms.room_of("a") == "r1" and h.hub.connections.by_player["a"] == a2


@pytest.mark.parametrize(
    ("name", "rate_hz"), [("Ann", None), ("A", 90.0)], ids=["new name", "new input rate"]
)
def test_a_reconnect_with_another_name_or_input_rate_leaves_and_joins_again(
    name: str, rate_hz: float | None
) -> None:
    """The room learns the new name from a fresh join; the engine takes the new rate's
    frame queue. The same name and rate take over silently (the test above)."""
    h = Harness()
    a1, b = h.join("a"), h.join("b")
    h.send(a1, walk_frame(0))
    h.inbox(a1), h.inbox(b)
    assert [op.kind for op in h.hub.take_tick_input().ops] == [EngineOpKind.ADD]
    a2 = h.hub.connect("10.0.0.1", h.now)
    h.send(a2, Hello(1, token(room="r1", player="a"), "r1", name, rate_hz=rate_hz))
    assert h.codes(a1) == ["REPLACED"]
    assert isinstance(h.inbox(a2)[0], Welcome)
    assert h.inbox(b) == [Presence("leave", "r1", "a", "A"), Presence("join", "r1", "a", name)]
    assert h.hub.rooms.name_of("a") == name
    for seq in (1, 2):  # two frames in one tick: a fast sender keeps only its newest
        h.send(a2, walk_frame(seq))
    ops = h.hub.take_tick_input().ops
    assert [(op.kind, op.player) for op in ops] == [
        (EngineOpKind.REMOVE, "a"),
        (EngineOpKind.ADD, "a"),
    ]
    superseded = {"reason": "superseded"}
    assert h.hub.metrics.value("posecast_frames_dropped_total", superseded) == (rate_hz == 90)


def test_bye_burns_the_token() -> None:
    h = Harness()
    tok = token(player="a")
    a = h.join("a", tok=tok)
    h.send(a, Bye("done"))
    assert isinstance(h.inbox(a)[-1], Bye)
    h.hub.disconnect(a, h.now)
    again = h.join("a", tok=tok)
    assert h.codes(again) == ["UNAUTHENTICATED"]


def test_backend_kicks_a_player_it_watches_but_no_other() -> None:
    h = Harness()
    a, other = h.join("a"), h.join("x", room="r9")
    be = h.join("be", role="backend", rooms=("r2",))
    watcher = h.inbox(be)
    assert isinstance(watcher[0], Welcome) and [m.player for m in watcher[0].members] == ["a"]
    h.inbox(a), h.inbox(other)
    h.send(a, walk_frame(0))  # a is in the engine now
    h.send(be, Kick("x"))
    assert h.codes(be) == ["NOT_FOUND"]
    h.send(be, Kick("a", "cheating"))
    (kicked,) = h.inbox(a)
    assert isinstance(kicked, Error) and (kicked.code, kicked.message) == ("KICKED", "cheating")
    assert h.hub.rooms.room_of("a") is None
    assert (EngineOpKind.REMOVE, "a") in [
        (op.kind, op.player) for op in h.hub.take_tick_input().ops
    ]


def test_fatal_errors_end_the_session_and_leave_the_room() -> None:
    h = Harness()
    a, b = h.join("a"), h.join("b")
    h.inbox(a), h.inbox(b)
    h.hub.receive(a, b"\xc1", h.now)
    assert h.codes(a) == ["MALFORMED"]
    assert h.hub.connections.conns[a].session.phase is Phase.CLOSED
    assert h.inbox(b) == [Presence("leave", "r1", "a", "A")]
    assert h.hub.metrics.value("posecast_errors_total", {"code": "MALFORMED"}) == 1


@pytest.mark.parametrize("version", [1, 2])
def test_text_frames_are_malformed_and_close_with_1003(version: int) -> None:
    h = Harness()
    a = h.join("a", version=version)
    h.inbox(a)
    h.hub.receive(a, '{"type": "ping"}', h.now)
    (error,) = [m for m in h.inbox(a) if isinstance(m, Error)]
    assert error.code == "MALFORMED"
    # The reason names no version: a v2 client was told "posecast v1 uses ...".
    assert error.message == "posecast uses binary WebSocket messages only (msgpack)"
    assert h.hub.outbox(a).close_code == 1003  # type: ignore[union-attr]


def test_room_full() -> None:
    h = Harness(max_players_per_room=1)
    h.join("a")
    b = h.join("b")
    assert h.codes(b) == ["ROOM_FULL"]


def test_a_player_of_a_full_room_may_join_it_again_with_another_layout() -> None:
    """Its seat is its own: the new connection replaces the old one (REPLACED there),
    rather than being refused as ROOM_FULL for a seat it holds."""
    from posecast.online.protocol.messages import Welcome
    from tests.online.conftest import token

    h = Harness(max_players_per_room=1)
    old = h.join("a")
    h.inbox(old)
    new = h.hub.connect("10.0.0.1", h.now)
    h.send(new, Hello(1, token(room="r1", player="a"), "r1", "A", layout="hmd3"))
    assert any(isinstance(m, Welcome) for m in h.inbox(new))
    assert h.codes(old) == ["REPLACED"]
    assert h.codes(h.join("b")) == ["ROOM_FULL"]  # and the room is still full


def test_non_fatal_error_replies_are_budgeted_but_all_counted() -> None:
    h = Harness(error_rate_hz=5.0)
    a = h.join("a")
    h.inbox(a)
    for _ in range(20):
        h.send(a, Kick("zz"))  # a player may not kick
    assert h.codes(a) == ["FORBIDDEN"] * 5
    assert h.hub.metrics.value("posecast_errors_total", {"code": "FORBIDDEN"}) == 20


def _ticks(h: Harness, start: float, until: float) -> None:
    """check_timeouts once a tick from ``start`` to ``until``, as the ticker calls it."""
    t = start
    while t <= until:
        h.hub.check_timeouts(t)
        t += 1.0 / h.hub.cfg.tick_hz


def test_timeouts_and_slow_consumers() -> None:
    h = Harness(hello_timeout_s=1.0, slow_consumer_s=2.0, idle_timeout_s=30.0)
    silent = h.hub.connect("10.0.0.2", h.now)
    slow = h.join("slow")
    _ticks(h, h.now, h.now + 1.5)
    assert h.codes(silent) == ["TIMED_OUT"]
    box = h.hub.outbox(slow)
    assert box is not None
    box.take()  # the writer took the welcome and is stuck sending it
    _ticks(h, h.now + 1.5, h.now + 2.5)
    assert slow in h.hub.pop_aborts()
    assert h.hub.metrics.value("posecast_errors_total", {"code": "SLOW_CONSUMER"}) == 1
    idle = h.join("idle")
    quiet = h.join("quiet", role="spectator")  # watchers only receive; pings keep them
    h.inbox(idle), h.inbox(quiet)
    _ticks(h, h.now + 2.5, h.now + 31.0)
    assert h.codes(idle) == ["TIMED_OUT"] and h.codes(quiet) == []


def test_a_server_stall_is_not_charged_to_its_clients() -> None:
    """After the event loop or the tick was held up, the clients' timeouts leave that
    time out: a writer that could not run was not a slow consumer, a hello or a frame
    that waited in the kernel did not time out. Time that passes tick by tick still
    counts (the test above)."""
    h = Harness(hello_timeout_s=1.0, slow_consumer_s=2.0, idle_timeout_s=3.0)
    silent = h.hub.connect("10.0.0.2", h.now)
    slow = h.join("slow")
    idle = h.join("idle")
    h.inbox(idle)
    box = h.hub.outbox(slow)
    assert box is not None
    box.take()  # in flight when the server stalls
    h.hub.check_timeouts(h.now)
    h.hub.check_timeouts(h.now + 5.0)  # the next check, 5 s later: the server was late
    assert h.hub.pop_aborts() == set()
    assert h.codes(silent) == [] and h.codes(idle) == []
    assert h.hub.metrics.value("posecast_errors_total", {"code": "SLOW_CONSUMER"}) == 0
    assert h.hub.metrics.value("posecast_server_late_seconds_total") > 4.9
    _ticks(h, h.now + 5.0, h.now + 8.5)  # then time the clients own
    assert slow in h.hub.pop_aborts()
    assert h.codes(silent) == ["TIMED_OUT"]


def test_shutdown_says_bye_to_everyone() -> None:
    h = Harness()
    conns = [h.join(p) for p in "abc"]
    for conn in conns:
        h.inbox(conn)
    h.hub.shutdown(h.now)
    for conn in conns:
        (bye,) = h.inbox(conn)
        box = h.hub.outbox(conn)
        assert isinstance(bye, Bye) and bye.reason == "SERVER_SHUTDOWN"
        assert box is not None and (box.close_code, box.close_reason) == (1001, "SERVER_SHUTDOWN")


def test_timeouts_do_not_spend_the_budget_but_an_oversized_message_does() -> None:
    hub, now = Hub(make_cfg(fatal_per_ip_per_min=1, hello_timeout_s=1.0), Metrics()), time.time()
    hub.connect(IP, now)
    hub.check_timeouts(now + 2.0)  # no hello in time: TIMED_OUT, fatal
    assert hub.admits(IP, now + 2.0)
    conn = _joined(hub, "p", now)
    too_large = TooLargeError("WebSocket: over size limit")  # websockets closed it 1009
    hub.refused_by_transport(conn, too_large, now)
    assert hub.metrics.value("posecast_errors_total", {"code": "TOO_LARGE"}) == 1
    assert not hub.admits(IP, now)


def test_a_bug_while_admitting_a_hello_ends_the_connection_with_internal(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    from posecast.online.core.admission import Admission

    hub, now = Hub(make_cfg(), Metrics()), time.time()

    def broken(self: Admission, *args: object) -> None:
        raise RuntimeError("a bug in the join")

    monkeypatch.setattr(Admission, "_join", broken)
    conn = hub.connect(IP, now)
    hub.receive(conn, encode(Hello(1, token(player="p"), "r1", "P")), now)
    (err,) = _inbox(hub, conn)
    assert isinstance(err, Error) and (err.code, err.fatal) == ("INTERNAL", True)
    box = hub.outbox(conn)
    assert box is not None and box.closed and box.close_code == 1011
    assert hub.rooms.room_of("p") is None and "p" not in hub.connections.by_player


def test_a_client_announcing_more_than_the_tick_rate_gets_a_queue_of_one() -> None:
    hub, now = Hub(make_cfg(), Metrics()), time.time()
    fast = hub.connect(IP, now)
    hub.receive(fast, encode(Hello(1, token(player="f"), "r1", "F", rate_hz=90.0)), now)
    slow = _joined(hub, "s", now)
    for seq in range(2):
        hub.receive(fast, encode(walk_frame(seq)), now)
        hub.receive(slow, encode(walk_frame(seq)), now)
    first = hub.take_tick_input().frames
    assert (first["f"].seq, first["s"].seq) == (1, 0)  # the 90 Hz one keeps its newest
    assert set(hub.take_tick_input().frames) == {"s"}
