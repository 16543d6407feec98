"""Players on other nodes (posecast.online.core.remote): announcements against snapshots."""

from __future__ import annotations

from posecast.online.core.remote import RemoteRooms
from posecast.online.protocol.messages import (
    Member,
)


def test_snapshot_never_undoes_a_newer_announcement() -> None:
    r = RemoteRooms()
    assert r.join("r1", "a", "n1", "A", now=10.0)
    # A read issued before a's join does not remove it ...
    assert r.snapshot("r1", {}, issued_at=9.0) == ([], [])
    # ... nor does one issued before b's leave bring b back.
    r.join("r1", "b", "n1", "B", now=10.0)
    assert r.leave("r1", "b", "n1", now=11.0) is not None
    joined, left = r.snapshot("r1", {"a": ("n1", "A"), "b": ("n1", "B")}, issued_at=10.5)
    assert (joined, left) == ([], [])
    # A read issued after both is the truth: b is gone, c is new, a left silently.
    joined, left = r.snapshot("r1", {"c": ("n2", "C")}, issued_at=12.0)
    assert joined == [Member("c", "C")] and left == [Member("a", "A")]
    # A leave from a node the player has moved away from changes nothing.
    r.join("r1", "c", "n3", "C", now=13.0)
    assert r.leave("r1", "c", "n2", now=14.0) is None and r.count("r1") == 1
