"""The hub (posecast.online.core.hub): rooms, routing and endings, without sockets."""

from __future__ import annotations

import time
from typing import Any

from posecast.online.core.hub import Hub
from posecast.online.core.session import Phase
from posecast.online.core.tick import TickOutput
from posecast.online.metrics import Metrics
from posecast.online.protocol import decode, encode
from posecast.online.protocol.messages import (
    Bye,
    Error,
    Hello,
    Kick,
    Member,
    Message,
    Presence,
    Welcome,
)
from tests.online.conftest import make_cfg, token, walk_frame


class Harness:
    def __init__(self, **cfg: Any) -> None:
        self.hub = Hub(make_cfg(**cfg), Metrics())
        self.now = time.time()

    def join(self, player: str, room: str = "r1", role: str = "player", **kw: Any) -> int:
        conn = self.hub.connect("10.0.0.1", self.now)
        tok = kw.pop("tok", None) or token(room=room, player=player, role=role, **kw)
        watch = tuple(kw.get("rooms", ())) if role == "backend" else ()
        self.send(conn, Hello(1, tok, room, player.upper(), watch=watch))
        return conn

    def send(self, conn: int, msg: Message) -> None:
        self.hub.receive(conn, encode(msg), self.now)

    def inbox(self, conn: int) -> list[Message]:
        box = self.hub.outbox(conn)
        assert box is not None
        out = [decode(d) for d in box.take()]
        box.sent(self.now)
        return out

    def codes(self, conn: int) -> list[str]:
        return [m.code for m in self.inbox(conn) if isinstance(m, Error)]


def test_joining_gives_welcome_with_members_and_tells_the_room() -> None:
    h = Harness()
    a = h.join("a")
    (welcome_a,) = h.inbox(a)
    assert isinstance(welcome_a, Welcome) and welcome_a.members == (Member("a", "A"),)
    b = h.join("b")
    (welcome_b,) = h.inbox(b)
    assert isinstance(welcome_b, Welcome) and [m.player for m in welcome_b.members] == ["a", "b"]
    assert h.inbox(a) == [Presence("join", "r1", "b", "B")]
    assert h.hub.take_tick_input().ops == []  # a player enters the engine with its first frame
    h.send(b, walk_frame(0))
    h.send(a, walk_frame(0))
    tick = h.hub.take_tick_input()
    assert [(op.kind, op.player) for op in tick.ops] == [("add", "b"), ("add", "a")]
    assert set(tick.frames) == {"a", "b"}


def test_two_frames_in_one_tick_are_both_stepped_and_a_third_supersedes() -> None:
    h = Harness()
    a = h.join("a")
    for seq in range(3):
        h.send(a, walk_frame(seq))
    seqs = [h.hub.take_tick_input().frames.get("a") for _ in range(3)]
    assert [f.seq if f else None for f in seqs] == [1, 2, None]  # oldest kept first
    assert h.hub.metrics.value("posecast_frames_dropped_total", {"reason": "superseded"}) == 1


def test_with_a_queue_of_one_the_newest_frame_wins() -> None:
    h = Harness(frame_queue=1)
    a = h.join("a")
    for seq in range(3):
        h.send(a, walk_frame(seq))
    frames = h.hub.take_tick_input().frames
    assert frames["a"].seq == 2 and h.hub.take_tick_input().frames == {}
    assert h.hub.metrics.value("posecast_frames_dropped_total", {"reason": "superseded"}) == 2


def test_poses_reach_the_room_audience_only() -> None:
    h = Harness()
    a, b, c = h.join("a"), h.join("b"), h.join("c", room="r2")
    spec = h.join("s", role="spectator")
    for conn in (a, b, c, spec):
        h.inbox(conn)
    h.hub.deliver(TickOutput([("a", b"pose-a"), ("c", b"pose-c")]), h.now)
    h.hub.deliver(TickOutput([("a", b"pose-a2"), ("c", b"pose-c2")]), h.now)  # nobody read
    raw = {conn: h.hub.outbox(conn).take() for conn in (a, b, c, spec)}  # type: ignore[union-attr]
    assert raw == {a: [b"pose-a2"], b: [b"pose-a2"], c: [b"pose-c2"], spec: [b"pose-a2"]}
    assert h.hub.metrics.value("posecast_poses_superseded_total") == 4


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
    assert ("remove", "a") in [(op.kind, op.player) for op in h.hub.take_tick_input().ops]


def test_fatal_errors_end_the_session_and_leave_the_room() -> None:
    h = Harness()
    a, b = h.join("a"), h.join("b")
    h.inbox(a), h.inbox(b)
    h.hub.receive(a, b"\xc1", h.now)
    assert h.codes(a) == ["MALFORMED"]
    assert h.hub.connections.conns[a].session.phase is Phase.CLOSED
    assert h.inbox(b) == [Presence("leave", "r1", "a", "A")]
    assert h.hub.metrics.value("posecast_errors_total", {"code": "MALFORMED"}) == 1


def test_text_frames_are_malformed_and_close_with_1003() -> None:
    h = Harness()
    a = h.join("a")
    h.inbox(a)
    h.hub.receive(a, '{"type": "ping"}', h.now)
    assert h.codes(a) == ["MALFORMED"]
    assert h.hub.outbox(a).close_code == 1003  # type: ignore[union-attr]


def test_room_full() -> None:
    h = Harness(max_players_per_room=1)
    h.join("a")
    b = h.join("b")
    assert h.codes(b) == ["ROOM_FULL"]


def test_non_fatal_error_replies_are_budgeted_but_all_counted() -> None:
    h = Harness(error_rate_hz=5.0)
    a = h.join("a")
    h.inbox(a)
    for _ in range(20):
        h.send(a, Kick("zz"))  # a player may not kick
    assert h.codes(a) == ["FORBIDDEN"] * 5
    assert h.hub.metrics.value("posecast_errors_total", {"code": "FORBIDDEN"}) == 20


def test_timeouts_and_slow_consumers() -> None:
    h = Harness(hello_timeout_s=1.0, slow_consumer_s=2.0, idle_timeout_s=30.0)
    silent = h.hub.connect("10.0.0.2", h.now)
    slow = h.join("slow")
    h.hub.check_timeouts(h.now + 1.5)
    assert h.codes(silent) == ["TIMED_OUT"]
    box = h.hub.outbox(slow)
    assert box is not None
    box.take()  # the writer took the welcome and is stuck sending it
    h.hub.check_timeouts(h.now + 2.5)
    assert slow in h.hub.pop_aborts()
    assert h.hub.metrics.value("posecast_errors_total", {"code": "SLOW_CONSUMER"}) == 1
    idle = h.join("idle")
    quiet = h.join("quiet", role="spectator")  # watchers only receive; pings keep them
    h.inbox(idle), h.inbox(quiet)
    h.hub.check_timeouts(h.now + 31.0)
    assert h.codes(idle) == ["TIMED_OUT"] and h.codes(quiet) == []


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


def test_a_player_that_moves_here_from_a_failed_node_is_not_announced_gone() -> None:
    """Node B dies; its player rejoins here. When B's records expire (the snapshot no
    longer lists the player on B) or B's late leave arrives, the room must not hear
    ``leave`` for a player who is playing right here."""
    h = Harness()
    a = h.join("a")
    h.inbox(a)
    h.hub.sink.remote_snapshot("r1", {"m": ("node-b", "M")}, h.now, h.now)
    assert h.inbox(a) == [Presence("join", "r1", "m", "M")]
    m = h.join("m")  # the SDK failed over to this node
    assert isinstance(h.inbox(m)[0], Welcome)
    assert h.inbox(a) == [Presence("join", "r1", "m", "M")]  # an upsert for clients
    assert h.hub.remote.get("r1", "m") is None  # no longer counted as on node B
    h.hub.sink.remote_snapshot("r1", {}, h.now + 5.0, h.now + 5.0)  # B's records expired
    h.hub.sink.remote_leave("r1", "m", "node-b", h.now + 5.0)  # or B's leave, late
    assert h.inbox(a) == []
    # A player who really is remote still leaves normally.
    h.hub.sink.remote_snapshot("r1", {"q": ("node-c", "Q")}, h.now + 6.0, h.now + 6.0)
    h.hub.sink.remote_leave("r1", "q", "node-c", h.now + 6.0)
    assert h.inbox(a) == [Presence("join", "r1", "q", "Q"), Presence("leave", "r1", "q", "Q")]


def test_a_keep_snapshot_adds_members_but_removes_none() -> None:
    """Right after Redis comes back empty, reads may miss nodes that have not
    re-registered yet: such a read (``keep``) must not announce them gone."""
    h = Harness()
    a = h.join("a")
    h.inbox(a)
    h.hub.sink.remote_snapshot("r1", {"m": ("node-b", "M")}, h.now, h.now)
    h.hub.sink.remote_snapshot("r1", {"q": ("node-c", "Q")}, h.now + 1, h.now + 1, keep=True)
    assert h.inbox(a) == [Presence("join", "r1", "m", "M"), Presence("join", "r1", "q", "Q")]
    assert {m.player for m in h.hub.remote.members("r1")} == {"m", "q"}
    h.hub.sink.remote_snapshot("r1", {"q": ("node-c", "Q")}, h.now + 5, h.now + 5)  # grace over
    assert h.inbox(a) == [Presence("leave", "r1", "m", "M")]
