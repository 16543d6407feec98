"""The engine worker and tick loop (posecast.online.shell.ticker), on the real ONNX engine."""

from __future__ import annotations

import asyncio
import threading
import time
from collections.abc import Awaitable, Callable
from concurrent.futures import ThreadPoolExecutor

import numpy as np
import pytest

from posecast.online.config import ServerConfig
from posecast.online.core.tick import EngineOp, EngineOpKind, TickInput, TickOutput
from posecast.online.engine.calibration import Calibration
from posecast.online.engine.multi import MultiEngine
from posecast.online.engine.selectors import AnomalySelector
from posecast.online.engine.ssi import Engine
from posecast.online.engine.types import TrackerFrame
from posecast.online.protocol import decode
from posecast.online.protocol.messages import Pose
from posecast.online.shell.ticker import EngineWorker, run_ticks
from posecast.skeleton import Joint
from posecast.tracking.layouts import Layout
from tests.online.conftest import make_cfg, walk_frame


def _frame(seq: int, seed: int = 0) -> TrackerFrame:
    f = walk_frame(seq, seed)
    return TrackerFrame(f.seq, f.pos, f.quat)


@pytest.fixture
def worker(engine_factory: Callable[[ServerConfig], Callable[[], Engine]]) -> EngineWorker:
    cfg = make_cfg(lookahead=2, delayed_emission=True)  # the paper's: poses 2 ticks late
    return EngineWorker(MultiEngine({"hmd3+waist": engine_factory(cfg)()}))


def test_one_step_batches_every_player_and_encodes_their_poses(worker: EngineWorker) -> None:
    ops = [EngineOp(EngineOpKind.ADD, p, seed=i) for i, p in enumerate("abc")]
    out = worker.step(TickInput(ops, {p: _frame(0, i) for i, p in enumerate("abc")}), 5.0)
    assert out.batch == 3 and out.poses == []  # tau = 2: nothing out yet
    for seq in (1, 2):
        out = worker.step(TickInput([], {p: _frame(seq) for p in "abc"}), 5.0)
    assert [p.player for p in out.poses] == ["a", "b", "c"]
    pose = decode(out.poses[0].v1())
    assert isinstance(pose, Pose) and pose.seq == 0 and pose.t == 5.0
    assert pose.positions.shape == (19, 3) and np.isfinite(pose.positions).all()
    assert out.seconds > 0


def test_ops_apply_in_order_and_tolerate_races(worker: EngineWorker) -> None:
    e = worker.engine
    worker.step(
        TickInput([EngineOp(EngineOpKind.ADD, "a"), EngineOp(EngineOpKind.REMOVE, "a")], {}), 0.0
    )
    assert e.player_count == 0
    worker.step(
        TickInput(
            [EngineOp(EngineOpKind.REMOVE, "ghost"), EngineOp(EngineOpKind.SELECTOR, "ghost")], {}
        ),
        0.0,
    )
    worker.step(
        TickInput(
            [EngineOp(EngineOpKind.ADD, "a"), EngineOp(EngineOpKind.ADD, "a")], {"zz": _frame(0)}
        ),
        0.0,
    )
    assert e.player_count == 1
    cal = Calibration.from_height(1.9)
    sel = AnomalySelector(5.0)
    worker.step(
        TickInput(
            [
                EngineOp(EngineOpKind.CALIBRATION, "a", calibration=cal),
                EngineOp(EngineOpKind.SELECTOR, "a", selector=sel),
            ],
            {},
        ),
        0.0,
    )
    inner = e.engines[e.players["a"]].players["a"]
    assert inner.calibration == cal and inner.selector == sel


def test_poses_wait_for_the_first_frame(worker: EngineWorker) -> None:
    worker.step(TickInput([EngineOp(EngineOpKind.ADD, "a")], {}), 0.0)
    for _ in range(5):
        out = worker.step(TickInput([], {}), 0.0)
    assert out.poses == []  # held rest poses of a player who never sent are not shown


@pytest.mark.timeout(10)
def test_tick_loop_runs_engine_work_in_one_dedicated_thread(worker: EngineWorker) -> None:
    threads: set[str] = set()
    delivered: list[TickOutput] = []
    step = worker.step

    def spy(inp: TickInput, t: float) -> TickOutput:
        threads.add(threading.current_thread().name)
        return step(inp, t)

    worker.step = spy  # type: ignore[method-assign]

    inputs = iter([TickInput([EngineOp(EngineOpKind.ADD, "a")], {})] + [TickInput([], {})] * 1000)

    async def ten_ticks(task: asyncio.Task[None]) -> None:
        while len(delivered) < 10:
            await asyncio.sleep(0.005)

    t0 = time.monotonic()
    _tick(
        worker,
        lambda: next(inputs),
        lambda out, now: delivered.append(out),
        lambda now: None,
        ten_ticks,
    )
    elapsed = time.monotonic() - t0
    assert len(threads) == 1 and next(iter(threads)).startswith("engine")
    # Never faster than the 60 Hz period (a slower machine only takes longer): ten
    # ticks span at least nine periods.
    assert len(delivered) >= 10 and elapsed >= 9 / 60 - 1e-3, elapsed


def test_poses_whose_trackers_are_out_of_reach_are_counted(worker: EngineWorker) -> None:
    """A thrown controller (2 m from the body): every pose sent after it is reach-limited."""

    def thrown(seq: int) -> TrackerFrame:
        f = _frame(seq)
        pos = f.pos.copy()
        pos[1, 0] += 2.0  # the left controller
        return TrackerFrame(f.seq, pos, f.quat)

    counts = []
    for seq in range(5):
        ops = [EngineOp(EngineOpKind.ADD, "a"), EngineOp(EngineOpKind.ADD, "b")] if seq == 0 else []
        out = worker.step(TickInput(ops, {"a": thrown(seq), "b": _frame(seq)}), 0.0)
        counts.append((len(out.poses), out.reach_limited))
    assert counts[2:] == [(2, 1)] * 3  # tau = 2; only player a


def test_a_failing_op_does_not_drop_the_others_of_its_tick(
    worker: EngineWorker, monkeypatch: pytest.MonkeyPatch, caplog: pytest.LogCaptureFixture
) -> None:
    e = worker.engine
    worker.step(
        TickInput([EngineOp(EngineOpKind.ADD, "a"), EngineOp(EngineOpKind.ADD, "b")], {}), 0.0
    )

    def broken(player: str, selector: object) -> None:
        raise RuntimeError("a bug")

    monkeypatch.setattr(e, "set_selector", broken)
    ops = [
        EngineOp(EngineOpKind.SELECTOR, "a", selector=AnomalySelector(5.0)),
        EngineOp(EngineOpKind.REMOVE, "b"),
    ]
    worker.step(TickInput(ops, {}), 0.0)
    assert set(e.players) == {"a"}  # b's removal, after the failed op, was applied
    assert "engine op selector for player 'a' failed" in caplog.text


@pytest.mark.timeout(10)
def test_a_failing_delivery_does_not_stop_the_ticks(worker: EngineWorker) -> None:
    calls: list[int] = []

    def deliver(out: TickOutput, now: float) -> None:
        calls.append(1)
        if len(calls) == 1:
            raise RuntimeError("a bug")

    def after(now: float) -> None:
        if len(calls) == 2:
            raise RuntimeError("another")

    async def four_deliveries(task: asyncio.Task[None]) -> None:
        while len(calls) < 4 and not task.done():
            await asyncio.sleep(0.01)

    _tick(worker, lambda: TickInput([], {}), deliver, after, four_deliveries)
    assert len(calls) >= 4


def _tick(
    worker: EngineWorker,
    take_input: Callable[[], TickInput],
    deliver: Callable[[TickOutput, float], None],
    after: Callable[[float], None],
    wait: Callable[[asyncio.Task[None]], Awaitable[None]],
) -> None:
    """Run the 60 Hz tick loop on one engine thread until ``wait(task)`` returns, then
    stop it (a failure that ended the loop raises here)."""

    async def main() -> None:
        stop = asyncio.Event()
        with ThreadPoolExecutor(1, thread_name_prefix="engine") as pool:
            task = asyncio.create_task(
                run_ticks(
                    period_s=1 / 60,
                    executor=pool,
                    worker=worker,
                    take_input=take_input,
                    deliver=deliver,
                    after=after,
                    overrun=lambda: None,
                    stop=stop,
                )
            )
            await wait(task)
            stop.set()
            await task

    asyncio.run(main())


@pytest.fixture(scope="module")
def both_layouts() -> MultiEngine:
    from posecast.online.engine.config import EngineConfig
    from posecast.online.inference.loader import load_engine

    ecfg = EngineConfig(samples=8, lookahead=1)
    return MultiEngine({lay: load_engine(ecfg, layout=lay, backend="onnx")
                        for lay in ("hmd3+waist", "hmd3")})  # fmt: skip


def _at_edge(seq: int, edge: np.ndarray, yaw_deg: float, layout: str) -> TrackerFrame:
    """A walk frame turned by ``yaw_deg`` and moved so that its head tracker sits at
    ``edge`` (on the wire's +-1000 m bounds), as a headset there sends it."""
    from posecast.geometry.rotations import quat_apply, quat_mul, yaw2quat
    from posecast.tracking.layouts import TrackerSlot

    f = walk_frame(seq)
    turn = yaw2quat(np.radians(yaw_deg))
    head = f.pos[TrackerSlot.HEAD]
    pos = quat_apply(turn, f.pos - head) + edge
    quat = quat_mul(np.broadcast_to(turn, f.quat.shape), f.quat)
    pos = np.clip(pos, -1000.0, 1000.0)  # what a decoder lets in
    if layout == "hmd3":
        pos[TrackerSlot.WAIST], quat[TrackerSlot.WAIST] = 0.0, (0.0, 0.0, 0.0, 1.0)
    return TrackerFrame(f.seq, pos, quat)


@pytest.mark.parametrize("layout", ["hmd3+waist", "hmd3"])
def test_poses_at_the_edges_of_the_tracking_space_stay_on_the_wire(
    both_layouts: MultiEngine, layout: str
) -> None:
    """A headset-only player at x = 1000 m facing 90 or 135 degrees got a pelvis beyond
    +-1000 m: v1 clients received a root their SDK refused, v2 clients no pose at all.
    Every pose at every edge, facing every way, is now one the wire carries: the v1
    message decodes, the v2 state exists, the root is inside, the head within a metre
    of its tracker."""
    from posecast.tracking.layouts import TrackerSlot

    worker = EngineWorker(both_layouts)
    edges = [np.array(e) * 1000.0 for e in ((1, 1.6e-3, 0), (-1, 1.6e-3, 0), (0, 1.6e-3, 1),
                                             (0, 1.6e-3, -1), (1, 1.6e-3, 1))]  # fmt: skip
    players = {f"p{i}-{yaw}": (edge, yaw) for i, edge in enumerate(edges)
               for yaw in (0, 90, 135, 180, 270)}  # fmt: skip
    ops = [EngineOp(EngineOpKind.ADD, p, layout=Layout(layout)) for p in players]
    shown = 0
    for seq in range(12):
        frames = {p: _at_edge(seq, e, y, layout) for p, (e, y) in players.items()}
        out = worker.step(TickInput(ops if seq == 0 else [], frames), 1.0)
        for p in out.poses:
            player, pose = p.player, decode(p.v1())
            assert isinstance(pose, Pose)
            assert np.abs(pose.positions[0]).max() <= 1000.0, (player, pose.positions[0])
            head = frames[player].pos[TrackerSlot.HEAD]
            assert np.linalg.norm(pose.positions[Joint.HEAD] - head) < 1.0
            assert p.state.root == tuple(round(c / 1e-4) for c in pose.positions[0])
            shown += 1
    assert worker.unencodable == 0
    assert shown >= len(players) * 8


def test_the_worker_forecasts_the_horizons_asked_and_only_those(
    engine_factory: Callable[[ServerConfig], Callable[[], Engine]],
) -> None:
    """Poses forecast 2 and 4 ticks ahead for ``a`` (its room's clients asked), stamped
    that far past the tick, same ``seq``; none for ``b``; none at all once nobody asks."""
    worker = EngineWorker(MultiEngine({"hmd3+waist": engine_factory(make_cfg())()}), 60.0)
    ops = [EngineOp(EngineOpKind.ADD, p, seed=i) for i, p in enumerate("ab")]
    asked = {"a": frozenset({2, 4})}
    outs = []
    for seq in range(8):
        inp = TickInput(ops if seq == 0 else [], {p: _frame(seq) for p in "ab"}, asked)
        outs.append(worker.step(inp, 10.0 + seq / 60))
    last = outs[-1]
    assert sorted(last.ahead) == [2, 4] and all(set(v) == {"a"} for v in last.ahead.values())
    base = {p.player: p for p in last.poses}["a"]
    for h, poses in last.ahead.items():
        fc = poses["a"]
        assert fc.seq == base.seq and fc.t == pytest.approx(base.t + h / 60)
        assert fc.v1() != base.v1()  # a walk moves: the forecast is not the pose held
    # the first poses, before a history of HISTORY frames, are held (stamped ahead)
    first = outs[0].ahead[4]["a"]
    assert first.offsets == outs[0].poses[0].offsets and first.t == pytest.approx(10 + 4 / 60)
    off = worker.step(TickInput([], {p: _frame(8) for p in "ab"}), 11.0)
    assert off.ahead == {} and not worker.history
