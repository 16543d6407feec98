"""The cluster sink (posecast.online.core.cluster_sink): other nodes' players in local rooms."""

from __future__ import annotations

from posecast.online.protocol.messages import (
    Presence,
    Welcome,
)
from tests.online.core.harness import Harness


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
