"""The connection table (online.core.connections): connections by id and by joined
player, and what the shell must do afterwards, collected: the writers to wake (each
once) and the sockets to abort."""

from __future__ import annotations

from posecast.online.core.connections import Conn, Connections
from posecast.online.core.outbox import Outbox
from posecast.online.core.ratelimit import TokenBucket
from posecast.online.core.session import Session
from tests.online.conftest import make_cfg


def _open(table: Connections, reliable_max: int = 4) -> Conn:
    conn = table.next_id()
    c = Conn(Session(conn, "127.0.0.1", make_cfg(), 0.0), Outbox(reliable_max), TokenBucket(5, 5))
    table.conns[conn] = c
    return c


def test_ids_are_new_and_players_map_to_their_connection() -> None:
    table = Connections()
    a, b = _open(table), _open(table)
    assert (a.session.conn, b.session.conn) == (1, 2) and table.next_id() == 3
    table.by_player["p1"] = b.session.conn
    assert table.get(1) is a and table.get(9) is None
    assert table.of_player("p1") is b and table.of_player("p2") is None
    del table.conns[2]  # closed before its player entry went: no connection
    assert table.of_player("p1") is None


def test_sends_mark_their_writer_dirty_once_until_popped() -> None:
    table = Connections()
    a, b = _open(table), _open(table)
    table.by_player["pa"] = a.session.conn
    table.send(a, b"welcome", 0.0)
    table.send_to_player("pa", b"presence", 0.1)
    table.send_to_player("nobody", b"lost", 0.1)  # no such player: nothing, no error
    assert table.pop_dirty() == {1} and table.pop_dirty() == set()
    assert a.outbox.take() == [b"welcome", b"presence"]
    assert table.pose_to_player("pa", "pb", b"pose1", 0.2) == 0
    assert table.pose_to_player("pa", "pb", b"pose2", 0.3) == 1  # superseded the unsent one
    assert table.pose_to_player("nobody", "pb", b"pose", 0.3) == 0
    assert table.pose_to_conn(b, "pa", b"pose", 0.3) == 0
    assert table.pop_dirty() == {1, 2}
    assert a.outbox.take() == [b"pose2"]


def test_a_final_message_closes_the_outbox_and_aborts_are_collected() -> None:
    table = Connections()
    a = _open(table, reliable_max=1)
    table.send(a, b"fills the queue", 0.0)
    table.final(a, b"error", 0.1, 4000, "kicked")
    assert a.outbox.closed and (a.outbox.close_code, a.outbox.close_reason) == (4000, "kicked")
    assert a.outbox.take() == [b"fills the queue", b"error"]  # the final one even when full
    assert table.pop_dirty() == {1}
    table.abort(1)
    table.abort(7)
    table.abort(1)
    assert table.pop_aborts() == {1, 7} and table.pop_aborts() == set()
