"""The hub (posecast.online.core.hub) as the shell sees it: a join, a frame, a tick."""

from __future__ import annotations

from posecast.online.core.tick import EngineOpKind
from posecast.online.protocol.messages import (
    Member,
    Presence,
    Welcome,
)
from tests.online.conftest import walk_frame
from tests.online.core.harness import Harness


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
    assert [(op.kind, op.player) for op in tick.ops] == [
        (EngineOpKind.ADD, "b"),
        (EngineOpKind.ADD, "a"),
    ]
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


def test_no_pose_of_a_player_goes_out_after_its_leave() -> None:
    """A pose of A waits unsent in a spectator's outbox when A disconnects: the
    spectator gets A's leave and no pose of A after it (which would bring back an avatar
    it has just removed)."""
    import numpy as np

    from posecast.online.core.tick import TickOutput
    from posecast.online.protocol.messages import Presence
    from posecast.testing.poses import pose_out

    h = Harness()
    spectator = h.join("s", role="spectator")
    a = h.join("a")
    h.inbox(spectator)
    pos = np.zeros((19, 3))
    pos[:, 1] = np.linspace(0.1, 1.7, 19)
    rot = np.tile([0.0, 0.0, 0.0, 1.0], (19, 1))
    h.hub.deliver(TickOutput(poses=[pose_out("a", 7, h.now, pos, rot)]), h.now)
    h.hub.disconnect(a, h.now)
    got = h.inbox(spectator)
    assert [(type(m).__name__, getattr(m, "event", None)) for m in got] == [("Presence", "leave")]
    assert isinstance(got[0], Presence) and got[0].player == "a"
