"""The cluster sink (posecast.online.core.cluster_sink): other nodes' players in local rooms."""

from __future__ import annotations

import msgpack
import pytest

from posecast.online.protocol.messages import (
    Presence,
    Welcome,
)
from posecast.online.protocol.pose_out import PoseOut
from posecast.testing.poses import pose_out
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


def _with_remote_m() -> tuple[Harness, int]:
    """Player a here, and m of node-b in room r1 (a's inbox read)."""
    h = Harness()
    a = h.join("a")
    h.hub.sink.remote_snapshot("r1", {"m": ("node-b", "M")}, h.now, h.now)
    h.inbox(a)
    return h, a


def test_a_tick_carries_stale_and_active_only_for_the_nodes_current_players() -> None:
    """A ``stale`` batched on node B before its player's leave can be read here after
    the leave: the room heard ``leave`` already and must not hear of the player again.
    A tick's events are never joins or leaves (those are announcements), nor another
    node's or room's players."""
    from posecast.online.protocol import encode

    h, a = _with_remote_m()
    sink = h.hub.sink
    stale = encode(Presence("stale", "r1", "m", "M"))
    sink.remote_tick("r1", "node-b", [], [stale], h.now)
    assert h.inbox(a) == [Presence("stale", "r1", "m", "M")]
    refused = [
        ("node-c", stale),  # not node-c's player
        ("node-b", encode(Presence("leave", "r1", "m", "M"))),
        ("node-b", encode(Presence("active", "r2", "m", "M"))),
        ("node-b", b"\xc1"),
    ]
    for node, data in refused:
        sink.remote_tick("r1", node, [], [data], h.now)
    sink.remote_leave("r1", "m", "node-b", h.now)
    sink.remote_tick("r1", "node-b", [], [encode(Presence("active", "r1", "m", "M"))], h.now)
    assert h.inbox(a) == [Presence("leave", "r1", "m", "M")]
    dropped = {"reason": "unknown_player"}
    assert h.hub.metrics.value("posecast_bus_dropped_total", dropped) == len(refused) + 1


def test_a_snapshot_ends_a_local_player_only_when_the_bus_vouches_for_the_read() -> None:
    """A snapshot listing a local player on another node may be a read that predates
    the player's own join here (it just moved from that node): it must not end the
    session. Only a player the bus reports ``replaced`` (read after this node's entry
    was written: another node took it over while its join could not cross) ends here,
    as the join would have ended it, and the room sees it move."""
    h = Harness()
    a, m = h.join("a"), h.join("m")
    h.inbox(a)
    assert isinstance(h.inbox(m)[0], Welcome)
    sink = h.hub.sink
    sink.remote_snapshot("r1", {"m": ("node-b", "M")}, h.now, h.now)  # a stale read
    assert h.inbox(m) == [] and h.inbox(a) == []
    assert h.hub.remote.get("r1", "m") is None
    sink.remote_snapshot("r1", {"m": ("node-b", "M")}, h.now, h.now, replaced=["m"])
    assert h.codes(m) == ["REPLACED"]
    assert h.inbox(a) == [Presence("leave", "r1", "m", "M"), Presence("join", "r1", "m", "M")]
    held = h.hub.remote.get("r1", "m")
    assert held is not None and held.node == "node-b"
    # A name the bus lists that is no local player (any more) changes nothing.
    sink.remote_snapshot("r1", {"m": ("node-b", "M")}, h.now, h.now, replaced=["m", "zz"])
    assert h.inbox(a) == []


def _pose(player: str, seq: int, t: float) -> PoseOut:
    """A pose as another node publishes it (its bus row, decoded here as the bus does)."""
    row = pose_out(player, seq, t).bus_row()
    pose = PoseOut.from_bus_row(msgpack.unpackb(msgpack.packb(row, use_bin_type=True)))
    assert pose is not None
    return pose


def test_a_remote_pose_goes_out_on_this_nodes_clock() -> None:
    """Node B's monotonic clock has another epoch (another host): its poses reach this
    node's clients with ``t`` on this node's clock, about when they arrived over the
    quickest path, and their spacing kept (clients interpolate on this clock)."""
    from posecast.online.protocol.messages import Pose

    h, a = _with_remote_m()
    sink = h.hub.sink
    base, delays = 5.0e6, [0.004, 0.002, 0.009, 0.002, 0.030]  # B's clock; bus delays
    got: list[float] = []
    for k, delay in enumerate(delays):
        t = base + k / 60
        sink.remote_tick("r1", "node-b", [_pose("m", k, t)], [], h.now + k / 60 + delay)
        (pose,) = h.inbox(a)
        assert isinstance(pose, Pose) and pose.seq == k
        got.append(pose.t)
    # The first two set the offset (4 then 2 ms of delay); after that it holds.
    assert abs(got[0] - (h.now + 0.004)) < 1e-6
    for k in range(1, len(delays)):
        assert abs(got[k] - (h.now + k / 60 + 0.002)) < 1e-4, k


def test_a_player_that_moved_rooms_keeps_its_avatar_until_it_is_gone_from_all() -> None:
    """Player m moves from room r1 (node B) to room r2 (node C), and this node hears of
    the join in r2 before the leave in r1: m's avatar id must stay while r2 holds it (an
    avatar id released there goes to the next player, whom r2's clients would take for m),
    and go once m has left everywhere."""
    h = Harness()
    a, b = h.join("a", version=2), h.join("b", room="r2", version=2)
    sink, avatars = h.hub.sink, h.hub.router.avatars
    sink.remote_snapshot("r1", {"m": ("node-b", "M")}, h.now, h.now)
    held = len(avatars)  # a, b and m
    sink.remote_join("r2", "m", "M", "node-c", h.now)
    sink.remote_leave("r1", "m", "node-b", h.now)
    assert len(avatars) == held
    sink.remote_leave("r2", "m", "node-c", h.now)
    assert len(avatars) == held - 1
    for conn in (a, b):
        h.inbox(conn)


def test_a_remote_players_time_never_goes_back_when_the_offset_drops() -> None:
    """Node B's first batch took a 100 ms round trip; the next, 5 ms, merged ticks 1-6
    latest-wins: q's tick-6 pose (which lowers B's offset) and m's tick-4 one (m sends
    at 15 Hz). m's tick-4 pose must not get a time before its tick-0 one: a client
    ordering poses by t would show it first, and the avatar would move back."""
    from posecast.online.protocol.messages import Pose

    h = Harness()
    a = h.join("a")
    sink = h.hub.sink
    sink.remote_snapshot("r1", {"m": ("node-b", "M"), "q": ("node-b", "Q")}, h.now, h.now)
    h.inbox(a)
    base, tick = 5.0e6, 1 / 60
    times: dict[str, list[float]] = {}

    def read() -> None:  # after each batch: a v1 outbox keeps a player's newest pose
        for msg in h.inbox(a):
            if isinstance(msg, Pose):
                times.setdefault(msg.player, []).append(msg.t)

    first = [_pose("q", 0, base), _pose("m", 0, base)]
    sink.remote_tick("r1", "node-b", first, [], h.now + 0.100)
    read()
    later = [_pose("q", 6, base + 6 * tick), _pose("m", 4, base + 4 * tick)]
    sink.remote_tick("r1", "node-b", later, [], h.now + 0.105)
    read()
    assert len(times["m"]) == 2 and times["m"][1] > times["m"][0], times
    assert times["q"][1] == pytest.approx(h.now + 0.105, abs=1e-6)  # the offset did drop


@pytest.mark.parametrize("gone_from_r1", ["leave", "snapshot", "last_audience"])
@pytest.mark.parametrize("new_node", ["node-b", "node-c"])
def test_a_remote_players_time_never_goes_back_when_it_moves_rooms(
    gone_from_r1: str, new_node: str
) -> None:
    """Player m of node B moves from room r1 to room r2 (on B again, or on node C), and
    this node hears of the join in r2 before m is gone from r1 (B's leave, a snapshot
    without m, or r1's last local audience leaving). m's time guard must outlive r1
    while r2 holds m: its older pose in a batch where q's newer one lowers the offset
    must not map before a time already sent. Once m is gone from every room, no guard
    is left for it."""
    from posecast.online.protocol.messages import Pose

    h = Harness()
    a, b = h.join("a"), h.join("b", room="r2")
    sink = h.hub.sink
    sink.remote_snapshot("r1", {"m": ("node-b", "M")}, h.now, h.now)
    sink.remote_snapshot("r2", {"q": (new_node, "Q")}, h.now, h.now)
    sink.remote_join("r2", "m", "M", new_node, h.now + 0.01)
    base, tick = 5.0e6, 1 / 60
    times: list[float] = []

    def read() -> None:
        times.extend(m.t for m in h.inbox(b) if isinstance(m, Pose) and m.player == "m")

    first = [_pose("q", 0, base), _pose("m", 0, base)]
    sink.remote_tick("r2", new_node, first, [], h.now + 0.100)
    read()
    if gone_from_r1 == "leave":
        sink.remote_leave("r1", "m", "node-b", h.now + 0.101)
    elif gone_from_r1 == "snapshot":
        sink.remote_snapshot("r1", {}, h.now + 0.101, h.now + 0.101)
    else:
        h.hub.disconnect(a, h.now + 0.101)
    assert h.hub.remote.get("r1", "m") is None and h.hub.remote.get("r2", "m") is not None
    later = [_pose("q", 6, base + 6 * tick), _pose("m", 4, base + 4 * tick)]
    sink.remote_tick("r2", new_node, later, [], h.now + 0.105)
    read()
    assert len(times) == 2 and times[1] > times[0], times
    # Gone from r2 too: m's guard is released (q's stays while q plays there).
    assert sink.clocks.guarded == 2
    sink.remote_leave("r2", "m", new_node, h.now + 0.2)
    assert sink.clocks.guarded == 1
    sink.remote_snapshot("r2", {}, h.now + 0.3, h.now + 0.3)
    assert sink.clocks.guarded == 0


def test_a_remote_player_that_moves_between_nodes_keeps_one_time_guard() -> None:
    """m moves within r1 from node B to node C (B's leave, stale by then, changes
    nothing): B's guard for m goes at once rather than when m leaves."""
    h, _ = _with_remote_m()
    sink = h.hub.sink
    sink.remote_tick("r1", "node-b", [_pose("m", 0, 5.0e6)], [], h.now + 0.01)
    sink.remote_join("r1", "m", "M", "node-c", h.now + 0.02)
    sink.remote_tick("r1", "node-c", [_pose("m", 1, 7.0e6)], [], h.now + 0.03)
    sink.remote_leave("r1", "m", "node-b", h.now + 0.04)
    assert sink.clocks.guarded == 1
    sink.remote_leave("r1", "m", "node-c", h.now + 0.05)
    assert sink.clocks.guarded == 0
