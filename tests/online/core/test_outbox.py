"""The latest-wins outbox (posecast.online.core.outbox)."""

from __future__ import annotations

from posecast.online.core.outbox import Outbox


def test_poses_supersede_per_player_and_control_goes_first() -> None:
    box = Outbox(reliable_max=4)
    box.put_pose("a", b"a1", 0.0)
    box.put_pose("b", b"b1", 0.0)
    box.put_reliable(b"presence", 0.0)
    box.put_pose("a", b"a2", 0.0)
    assert box.take() == [b"presence", b"b1", b"a2"]
    assert box.superseded == 1
    assert box.take() == []


def test_a_client_behind_by_many_ticks_gets_one_pose_per_player() -> None:
    box = Outbox(reliable_max=4)
    for tick in range(1000):
        for p in "abc":
            box.put_pose(p, f"{p}{tick}".encode(), tick / 60)
    assert box.take() == [b"a999", b"b999", b"c999"]


def test_reliable_queue_overflows_instead_of_growing() -> None:
    box = Outbox(reliable_max=2)
    assert box.put_reliable(b"1", 0.0) and box.put_reliable(b"2", 0.0)
    assert not box.put_reliable(b"3", 0.0)
    assert box.overflowed


def test_stall_clock_counts_only_while_the_writer_makes_no_progress() -> None:
    box = Outbox(reliable_max=4)
    assert box.stalled_for(5.0) == 0.0
    box.put_pose("a", b"x", 1.0)
    assert box.stalled_for(3.0) == 2.0
    box.take()  # the writer is now stuck sending it
    assert box.stalled_for(4.0) == 3.0 and not box.drained
    box.sent(4.0)
    assert box.stalled_for(9.0) == 0.0 and box.drained
    box.put_pose("a", b"y", 9.0)
    box.take()
    box.put_pose("a", b"z", 9.5)  # arrives while in flight
    box.sent(10.0)
    assert box.stalled_for(11.0) == 1.0


def test_final_message_drops_poses_and_closes() -> None:
    box = Outbox(reliable_max=1)
    box.put_reliable(b"full", 0.0)
    box.put_pose("a", b"pose", 0.0)
    box.put_final(b"bye", 0.0, 1001, "shutdown")
    box.put_pose("a", b"late", 0.0)
    box.put_reliable(b"late", 0.0)
    assert box.take() == [b"full", b"bye"]
    assert box.closed and (box.close_code, box.close_reason) == (1001, "shutdown")
