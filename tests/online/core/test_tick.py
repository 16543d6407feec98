"""The engine inbox (posecast.online.core.tick): when players enter and leave the
engine, and the per-player frame queue."""

from __future__ import annotations

import numpy as np

from posecast.online.core.tick import EngineInbox, EngineOp, EngineOpKind
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
    assert tick.ops == [EngineOp(EngineOpKind.ADD, "p", seed=7, layout=Layout.HMD3)]
    assert tick.ops[0].kind is EngineOpKind.ADD  # the member itself, not an equal string
    assert tick.frames["p"].seq == 0
    inbox.frame("p", _frame(1))
    inbox.left("p")
    tick = inbox.take()
    assert tick.ops == [EngineOp(EngineOpKind.REMOVE, "p")] and tick.frames == {}


def test_a_setting_before_any_frame_adds_the_player_first() -> None:
    inbox = EngineInbox()
    inbox.joined("p", seed=1, layout=Layout.HMD3_WAIST)
    inbox.setting(EngineOp(EngineOpKind.CALIBRATION, "p"))
    assert [op.kind for op in inbox.take().ops] == [EngineOpKind.ADD, EngineOpKind.CALIBRATION]


def test_the_queue_keeps_the_newest_frames_up_to_its_depth() -> None:
    inbox = EngineInbox(frame_queue=3)
    inbox.joined("p", seed=0, layout=Layout.HMD3_WAIST)
    dropped = [inbox.frame("p", _frame(seq)) for seq in range(5)]
    assert dropped == [False, False, False, True, True]
    assert [inbox.take().frames["p"].seq for _ in range(3)] == [2, 3, 4]
    assert inbox.take().frames == {}


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
    assert stepped == [0, 1, 2, 3, 4, 5, 6]


def test_a_player_with_a_queue_of_one_keeps_only_its_newest_frame() -> None:
    """What a client announcing more than the tick rate gets (a 90 Hz headset)."""
    inbox = EngineInbox()
    inbox.joined("p", seed=0, layout=Layout.HMD3_WAIST, queue=1)
    assert [inbox.frame("p", _frame(seq)) for seq in range(2)] == [False, True]
    assert inbox.take().frames["p"].seq == 1 and inbox.take().frames == {}


def test_a_client_faster_than_the_tick_that_never_said_so_gets_its_newest_frame() -> None:
    """A game engine streaming at a 90 Hz display rate, announced as 60 Hz (no
    ``rate_hz``): with a queue of two it would stay one tick behind for good. After two
    windows above 1.1 frames a tick it is stepped on its newest frame; a 60 Hz client
    that flushes a stall's frames in one window is not taken for fast."""
    from posecast.online.core.tick import RATE_WINDOW_TICKS

    inbox = EngineInbox()
    for p in ("fast", "flush"):
        inbox.joined(p, seed=0, layout=Layout.HMD3_WAIST)
    seq = {"fast": 0, "flush": 0}
    behind: list[int] = []  # per tick: the newest frame sent minus the one stepped

    def send(p: str, n: int) -> None:
        for _ in range(n):
            inbox.frame(p, _frame(seq[p]))
            seq[p] += 1

    windows = 4
    for tick in range(windows * RATE_WINDOW_TICKS):
        send("fast", 2 if tick % 2 else 1)  # 90 Hz: 3 frames every 2 ticks
        stalled = RATE_WINDOW_TICKS // 2 <= tick < RATE_WINDOW_TICKS
        flushed = tick == RATE_WINDOW_TICKS
        send("flush", 0 if stalled else 1 + (RATE_WINDOW_TICKS // 2 if flushed else 0))
        got = inbox.take().frames
        behind.append(seq["fast"] - 1 - got["fast"].seq)
    first, last = behind[:RATE_WINDOW_TICKS], behind[-RATE_WINDOW_TICKS:]
    assert max(first[5:]) >= 1  # a queue of two: behind
    assert max(last) == 0  # after two fast windows: the newest, every tick
    # The flush (a window of 90 frames after one of 30) never made "flush" fast: its
    # queue of two still steps its frames one by one.
    inbox.frame("flush", _frame(seq["flush"]))
    inbox.frame("flush", _frame(seq["flush"] + 1))
    assert inbox.take().frames["flush"].seq == seq["flush"]


def test_a_standing_backlog_is_drained_one_frame_after_half_a_second() -> None:
    """One bunch, then a frame every tick: without a gap every later frame would wait
    a tick more for good. After STANDING_TICKS takes that left a frame waiting, one
    take supersedes the oldest and steps the next: back to the newest frame."""
    from posecast.online.core.tick import STANDING_TICKS

    inbox = EngineInbox()
    inbox.joined("p", seed=0, layout=Layout.HMD3_WAIST)
    inbox.frame("p", _frame(0))
    seq, behind, drained = 1, [], 0
    for _ in range(2 * STANDING_TICKS + 5):
        inbox.frame("p", _frame(seq))
        seq += 1
        tick = inbox.take()
        drained += tick.drained
        behind.append(seq - 1 - tick.frames["p"].seq)
    assert behind[: STANDING_TICKS - 1] == [1] * (STANDING_TICKS - 1)
    assert drained == 1 and behind[STANDING_TICKS - 1 :] == [0] * (STANDING_TICKS + 6)


def test_a_backlog_that_clears_by_itself_loses_nothing() -> None:
    """A gap (a frame that came late) just before the backlog has stood
    STANDING_TICKS takes clears it: the count starts again, nothing is superseded."""
    from posecast.online.core.tick import STANDING_TICKS

    inbox = EngineInbox()
    inbox.joined("p", seed=0, layout=Layout.HMD3_WAIST)
    seq, stepped, drained = 0, [], 0
    for k in range(4 * STANDING_TICKS):
        # Every STANDING_TICKS ticks: a bunch of two, a frame a tick, a gap at the end.
        phase = k % STANDING_TICKS
        n = 2 if phase == 0 else (0 if phase == STANDING_TICKS - 1 else 1)
        for _ in range(n):
            inbox.frame("p", _frame(seq))
            seq += 1
        tick = inbox.take()
        drained += tick.drained
        if "p" in tick.frames:
            stepped.append(tick.frames["p"].seq)
    assert drained == 0 and stepped == list(range(len(stepped)))
