"""The engine inbox (posecast.online.core.tick): when players enter and leave the
engine, and the per-player frame queue."""

from __future__ import annotations

import numpy as np

from posecast.online.core.tick import EngineInbox, EngineOp
from posecast.online.engine.types import TrackerFrame
from posecast.tracking.layouts import Layout


def _frame(seq: int) -> TrackerFrame:
    return TrackerFrame(seq, np.zeros((4, 3)), np.tile([0.0, 0.0, 0.0, 1.0], (4, 1)))


def test_a_player_that_joins_and_leaves_without_a_frame_never_reaches_the_engine() -> None:
    inbox = EngineInbox()
    inbox.joined("p", seed=7, layout=Layout.HMD3)
    assert inbox.take().ops == []
    inbox.left("p")
    tick = inbox.take()
    assert tick.ops == [] and tick.frames == {}


def test_the_first_frame_adds_the_player_with_its_seed_and_layout_then_leave_removes() -> None:
    inbox = EngineInbox()
    inbox.joined("p", seed=7, layout=Layout.HMD3)
    inbox.frame("p", _frame(0))
    tick = inbox.take()
    assert tick.ops == [EngineOp("add", "p", seed=7, layout=Layout.HMD3)]
    assert tick.frames["p"].seq == 0
    inbox.frame("p", _frame(1))
    inbox.left("p")
    tick = inbox.take()
    assert tick.ops == [EngineOp("remove", "p")] and tick.frames == {}


def test_a_setting_before_any_frame_adds_the_player_first() -> None:
    inbox = EngineInbox()
    inbox.joined("p", seed=1, layout=Layout.HMD3_WAIST)
    inbox.setting(EngineOp("calibration", "p"))
    assert [op.kind for op in inbox.take().ops] == ["add", "calibration"]


def test_the_queue_keeps_the_newest_frames_up_to_its_depth() -> None:
    inbox = EngineInbox(frame_queue=3)
    inbox.joined("p", seed=0, layout=Layout.HMD3_WAIST)
    dropped = [inbox.frame("p", _frame(seq)) for seq in range(5)]
    assert dropped == [False, False, False, True, True]
    assert inbox.take().frames["p"].seq == 2
    assert inbox.take().frames["p"].seq == 4  # 3 waited a tick while 4 was there: late
    assert inbox.take().frames == {} and inbox.late == 1


def test_a_burst_at_the_tick_boundary_is_stepped_frame_by_frame() -> None:
    """60 Hz against 60 Hz with jitter: two frames in one tick, none in the next."""
    inbox = EngineInbox()
    inbox.joined("p", seed=0, layout=Layout.HMD3_WAIST)
    stepped = []
    for arrivals in ([0], [1, 2], [], [3], [4, 5], [], [6]):
        for seq in arrivals:
            inbox.frame("p", _frame(seq))
        got = inbox.take().frames.get("p")
        stepped.append(None if got is None else got.seq)
    assert stepped == [0, 1, 2, 3, 4, 5, 6] and inbox.late == 0


def test_a_client_faster_than_the_tick_builds_no_standing_backlog() -> None:
    """A 90 Hz headset: 1, 2, 1, 2, ... frames per 60 Hz tick. A frame that waited a
    tick while a newer one came is late and dropped: latency never grows."""
    inbox = EngineInbox()
    inbox.joined("p", seed=0, layout=Layout.HMD3_WAIST)
    seq, stepped = 0, []
    for tick in range(12):
        for _ in range(1 + tick % 2):
            inbox.frame("p", _frame(seq))
            seq += 1
        stepped.append(inbox.take().frames["p"].seq)
    newest_left = [seq_sent - 1 - s for s, seq_sent in zip(stepped, _sent_counts(12), strict=True)]
    assert max(newest_left) <= 1  # at most one newer frame waits behind the stepped one
    assert inbox.late > 0


def _sent_counts(ticks: int) -> list[int]:
    out, total = [], 0
    for tick in range(ticks):
        total += 1 + tick % 2
        out.append(total)
    return out
