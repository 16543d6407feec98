"""The room registry (posecast.online.core.rooms)."""

from __future__ import annotations

import pytest

from posecast.errors import RoomFullError
from posecast.online.core.rooms import Rooms


def _rooms(**kw: int) -> Rooms:
    return Rooms(**{"max_players": 2, "max_watchers": 2, "max_rooms": 3, **kw})


def test_audience_is_players_and_watchers_of_that_room_only() -> None:
    r = _rooms()
    r.add_player("a", "p1", "One")
    r.add_player("a", "p2", "Two")
    r.add_player("b", "p3", "Three")
    r.add_watcher(("a", "b"), "be")
    assert r.audience("a") == ("p1", "p2", "be")
    assert r.audience("b") == ("p3", "be")
    assert [m.player for m in r.members("a")] == ["p1", "p2"]
    assert r.room_of("p3") == "b" and r.name_of("p3") == "Three"


def test_leaving_empties_and_drops_rooms() -> None:
    r = _rooms()
    r.add_player("a", "p1", "One")
    r.add_watcher(("a", "b"), "be")
    assert r.remove("p1") == "a"
    assert set(r.rooms) == {"a", "b"}
    assert r.remove("be") is None
    assert r.rooms == {} and r.audience("a") == ()


def test_limits_raise_room_full() -> None:
    r = _rooms()
    r.add_player("a", "p1", "1")
    r.add_player("a", "p2", "2")
    with pytest.raises(RoomFullError, match="2 players"):
        r.add_player("a", "p3", "3")
    r.add_player("b", "p4", "4")
    r.add_player("c", "p5", "5")
    with pytest.raises(RoomFullError, match="3 rooms"):
        r.add_player("d", "p6", "6")
    r.add_watcher(("a",), "w1")
    r.add_watcher(("a",), "w2")
    with pytest.raises(RoomFullError, match="watchers"):
        r.add_watcher(("a",), "w3")
    assert r.player_count == 4
