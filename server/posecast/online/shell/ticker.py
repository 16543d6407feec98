"""The fixed-rate tick: take every player's waiting frame (the core's EngineInbox),
one batched engine step, the poses quantised once for every way out
(:class:`~posecast.online.protocol.pose_out.PoseOut`), handed back for broadcast.

All engine work, membership changes included, runs in ONE dedicated worker thread
(``ThreadPoolExecutor(max_workers=1)``), at tick boundaries, so socket I/O goes on
while the engine computes and the engine is never touched by two threads::

    event loop:    take_tick_input() --ops, frames--> |           | --TickOutput--> deliver()
    engine thread:                                     EngineWorker.step()

If a step takes longer than a period, the next one starts at once and the schedule
is reset rather than caught up: there is no backlog of ticks, frames in the meantime
wait in each player's short queue (past it, the oldest is superseded), and
``posecast_tick_overruns`` counts it.
"""

from __future__ import annotations

import asyncio
import logging
import time
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor

import numpy as np

from posecast.online.core.tick import EngineOp, EngineOpKind, TickInput, TickOutput
from posecast.online.engine.forecasting import ShownHistory
from posecast.online.engine.multi import MultiEngine
from posecast.online.engine.types import PoseOut as Shown
from posecast.online.protocol.pose_out import PoseOut
from posecast.online.protocol.quantize import roots_on_wire
from posecast.online.protocol.records import PoseState

log = logging.getLogger("posecast.ticker")


class EngineWorker:
    """Owns the :class:`~posecast.online.engine.multi.MultiEngine`; only ever called
    from the engine thread."""

    def __init__(self, engine: MultiEngine, tick_hz: float = 60.0) -> None:
        self.engine = engine
        self.tick_hz = tick_hz
        self.unencodable = 0  # poses dropped because quantising refused them
        self.history = ShownHistory()  # the shown poses of players some client forecasts

    def step(self, inp: TickInput, server_t: float) -> TickOutput:
        t0 = time.perf_counter()
        e = self.engine
        for op in inp.ops:
            try:
                self._apply(op)
            except Exception:  # a bug in one op must not drop the others of the tick
                log.exception("engine op %s for player %r failed", op.kind, op.player)
        for player, frame in inp.frames.items():
            if player in e.players:
                e.push(player, frame)
        result = e.tick()
        poses: list[PoseOut] = []
        ahead: dict[int, dict[str, PoseOut]] = {}
        # one pose per source frame: nothing new over a gap or when stale
        shown = [p for p in result.poses if not p.held and p.seq >= 0]
        if shown:
            positions = roots_on_wire(np.stack([p.positions for p in shown]))
            rotations = np.stack([p.rotations for p in shown])
            states = PoseState.batch(
                [p.player for p in shown],
                [p.seq for p in shown],
                server_t,
                positions,
                rotations,
                [p.scale for p in shown],
                [p.reach_limited for p in shown],
            )
            poses, refused = PoseOut.batch(states, positions, rotations)
            self.unencodable += refused  # a joint 32 m from the pelvis
            for p in poses:
                p.v1()  # the v1 bytes too, here in the engine thread, once
            if inp.horizons or self.history:  # only when a client asked for a forecast
                ahead = self._ahead(shown, positions, rotations, inp.horizons, server_t)
        limited = sum(p.state.reach_limited for p in poses)
        return TickOutput(
            poses,
            result.events,
            result.transitions,
            e.player_count,
            time.perf_counter() - t0,
            limited,
            ahead,
        )

    def _ahead(
        self,
        shown: list[Shown],
        positions: np.ndarray,
        rotations: np.ndarray,
        horizons: dict[str, frozenset[int]],
        server_t: float,
    ) -> dict[int, dict[str, PoseOut]]:
        """The poses forecast for each horizon (frames) clients asked for, stamped that
        far ahead of the tick (v2 only: no v1 bytes)."""
        players = [p.player for p in shown]
        got = self.history.step(
            players, [p.seq for p in shown], positions, rotations, horizons, self.tick_hz
        )
        out: dict[int, dict[str, PoseOut]] = {}
        for h, (at, fp, fr) in got.items():
            fp = roots_on_wire(fp)
            states = PoseState.batch(
                [players[i] for i in at],
                [shown[i].seq for i in at],
                server_t + h / self.tick_hz,
                fp,
                fr,
                [shown[i].scale for i in at],
                [shown[i].reach_limited for i in at],
            )
            made, refused = PoseOut.batch(states, fp, fr)
            self.unencodable += refused
            out[h] = {p.player: p for p in made}
        return out

    def _apply(self, op: EngineOp) -> None:
        e = self.engine
        present = op.player in e.players
        self.history.forget(op.player)  # any op starts the forecast's history again
        if op.kind is EngineOpKind.ADD:
            if present:  # rejoined before its removal was applied: start afresh
                e.remove_player(op.player)
            e.add_player(op.player, op.seed, op.layout)
        elif not present:
            return  # left before this op was applied
        elif op.kind is EngineOpKind.REMOVE:
            e.remove_player(op.player)
        elif op.kind is EngineOpKind.SELECTOR and op.selector is not None:
            e.set_selector(op.player, op.selector)
        elif op.kind is EngineOpKind.CALIBRATION and op.calibration is not None:
            e.set_calibration(op.player, op.calibration)


async def run_ticks(
    *,
    period_s: float,
    executor: ThreadPoolExecutor,
    worker: EngineWorker,
    take_input: Callable[[], TickInput],
    deliver: Callable[[TickOutput, float], None],
    after: Callable[[float], None],
    overrun: Callable[[], None],
    stop: asyncio.Event,
) -> None:
    """Tick every ``period_s`` until ``stop`` is set; one engine step at a time."""
    loop = asyncio.get_running_loop()
    next_t = loop.time()
    while not stop.is_set():
        inp = take_input()
        try:
            out = await loop.run_in_executor(executor, worker.step, inp, time.monotonic())
        except Exception:  # a bug in one step must not stop the server
            log.exception("engine step failed")
            out = TickOutput([])
        try:
            deliver(out, time.monotonic())
        except Exception:  # nor one delivery or housekeeping pass stop the ticks
            log.exception("delivering a tick failed")
        try:
            after(time.monotonic())
        except Exception:
            log.exception("the after-tick pass failed")
        next_t += period_s
        delay = next_t - loop.time()
        if delay < -period_s:
            overrun()
            next_t = loop.time()
            delay = 0.0
        await asyncio.sleep(max(0.0, delay))
