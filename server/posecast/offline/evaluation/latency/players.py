"""One client process of ``posecast bench latency``: Python SDK players that stream a
walk at 60 Hz, receive their room-mates' poses and show them through the SDK's
interpolator in a 90 Hz display loop (the asyncio shell around :mod:`.display`).

Each player is a :class:`posecast_client.Client` (``reconnect=False``: a lost
connection is a failed run, not a pause): its sender replays the SDK's procedural
walk (:class:`posecast_client.WalkSource`, a seed per player, its own phase within
the first frame period), stamping every frame with its capture time on the host's
monotonic clock; its reader feeds every event to its own
:class:`posecast_client.Interpolator` and notes when each room-mate's pose arrived.
One display loop per process samples every player's interpolator in turn, each at
its own ``time.monotonic()`` on the SDK's display clock
(``client.clock.display_time``), as a game's render loop would.

Run in a process of its own (:func:`run_worker`), it returns plain data: tuples and
dicts, picklable.
"""

from __future__ import annotations

import asyncio
import contextlib
import math
import random
import time
from collections import Counter
from dataclasses import dataclass, field
from typing import Any

import posecast_client as pc

from posecast.offline.evaluation.latency.display import Displayed, DisplayWatch, JumpMeter

TAIL_S = 1.5  # display goes on after the last frame, for the poses still on their way


@dataclass(frozen=True)
class PlayerPlan:
    """One player: its id, room, place in the room (it stands ``slot`` places from
    the others) and walk seed."""

    player: str
    room: str
    slot: int
    seed: int


@dataclass(frozen=True)
class WorkerPlan:
    """What one client process runs. Times are on the host's monotonic clock: frames
    from ``start_at`` to ``stop_at``; figures from ``measure_from``."""

    url: str
    secret: str
    players: tuple[PlayerPlan, ...]
    start_at: float
    measure_from: float
    stop_at: float
    display_hz: float = 90.0
    frame_hz: float = 60.0
    protocol: int = 2
    draw_all: bool = False  # every player samples its room-mates (else one per room here)


@dataclass
class WorkerResult:
    """What one client process measured (plain data)."""

    captures: dict[str, dict[int, float]] = field(default_factory=dict)  # id -> seq -> capture
    displayed: list[tuple[str, int, float, float, float]] = field(default_factory=list)
    drawn: int = 0  # how many of ``displayed`` (the first) drawing players displayed
    waiting: list[tuple[str, int, float, float]] = field(default_factory=list)  # never shown
    jumps_m: list[float] = field(default_factory=list)
    members: dict[str, str] = field(default_factory=dict)  # player id -> room
    welcome: dict[str, Any] = field(default_factory=dict)  # lookahead_frames, rate_hz, version
    errors: Counter[str] = field(default_factory=Counter)
    failures: list[str] = field(default_factory=list)  # players whose session ended early
    display_frames: int = 0
    display_frames_late: int = 0  # sampled more than half a period after their time
    cpu_s: float = 0.0  # this process's CPU over the measured window
    wall_s: float = 0.0


class _Receiver:
    """One player's receiving side: its interpolator and what it showed."""

    def __init__(self, client: pc.Client, me: str, display_hz: float, draws: bool) -> None:
        self.client = client
        self.me = me
        self.draws = draws  # samples its room-mates' poses each frame (else: their times)
        self.interp = pc.Interpolator()
        self.watch = DisplayWatch()
        self.jumps = JumpMeter(display_hz)
        self.displayed: list[Displayed] = []

    def feed(self, event: pc.Event, now: float) -> None:
        if isinstance(event, pc.Pose):
            if event.player == self.me:
                return  # its own avatar: a game draws that from its own trackers
            self.interp.feed(event)
            self.watch.received(event.player, event.seq, event.t, now)
            return
        self.interp.feed(event)
        if isinstance(event, pc.Presence) and event.event == "leave":
            self.watch.forget(event.player)
            self.jumps.forget(event.player)

    def show(self, record: bool) -> None:
        """One display frame, now: every room-mate sampled (a drawing receiver), or
        only the time each would show (``Interpolator.advance``: the same render
        delay and shown times, no sample)."""
        now = time.monotonic()
        at = self.client.clock.display_time(now)
        if not self.draws:
            self.displayed.extend(self.watch.frame(now, self.interp.advance(at)))
            return
        shown = self.interp.poses_at(at)
        self.displayed.extend(self.watch.frame(now, {p: s.t for p, s in shown.items()}))
        self.jumps.frame(now, {p: s.positions for p, s in shown.items()}, record=record)


async def _sleep_until(t: float) -> None:
    delay = t - time.monotonic()
    if delay > 0:
        await asyncio.sleep(delay)


async def _stream(
    client: pc.Client, plan: WorkerPlan, p: PlayerPlan, captures: dict[int, float]
) -> None:
    """Replay the walk from ``plan.start_at`` (plus a phase) until ``plan.stop_at``."""
    rng = random.Random(p.seed)
    await _sleep_until(plan.start_at + rng.random() / plan.frame_hz)
    offset = ((p.slot % 4) * 1.2, 0.0, (p.slot // 4) * 1.2)  # side by side, as posecast-sim
    # Long enough not to loop within the run: a loop jumps the walker back to its
    # start, a teleport every room-mate would show as the largest joint jump.
    seconds = max(10.0, plan.stop_at - plan.start_at + 2.0)
    source = pc.WalkSource(seconds=seconds, seed=p.seed, loop=True, offset_m=offset,
                           rate_hz=plan.frame_hz)  # fmt: skip
    async for s in source:
        assert s.t is not None
        if s.t >= plan.stop_at:
            return
        seq = await client.send_frame(s.positions, s.orientations, valid=s.valid, t=s.t)
        if seq is not None:
            captures[seq] = s.t


async def _read(client: pc.Client, receiver: _Receiver, out: WorkerResult) -> None:
    async for event in client.events():
        receiver.feed(event, time.monotonic())
        if isinstance(event, pc.Error):
            out.errors[event.code] += 1


async def _display(receivers: list[_Receiver], plan: WorkerPlan, out: WorkerResult) -> None:
    """The display loop: every receiver shown once a period until the tail ends; a
    frame more than a period late is skipped, as a compositor drops frames."""
    period = 1.0 / plan.display_hz
    start = time.monotonic()
    k = 0
    cpu0: float | None = None
    end = plan.stop_at + TAIL_S
    while True:
        due = start + k * period
        # Always yield, even when behind: a loop that only awaited when early would
        # starve the players' readers and senders on a busy machine.
        await asyncio.sleep(max(0.0, due - time.monotonic()))
        now = time.monotonic()
        if now >= end:
            break
        if now - due > period:
            k = math.floor((now - start) / period)  # dropped frames: on to the current one
            due = start + k * period
        record = plan.measure_from <= now < plan.stop_at
        if record:
            if cpu0 is None:
                cpu0, out.wall_s = time.process_time(), now
            out.display_frames += 1
            out.display_frames_late += now - due > period / 2
        elif cpu0 is not None and not out.cpu_s and now >= plan.stop_at:
            out.cpu_s, out.wall_s = time.process_time() - cpu0, now - out.wall_s
        for r in receivers:
            r.show(record)
        k += 1


async def _join(
    plan: WorkerPlan, p: PlayerPlan, clients: list[pc.Client]
) -> tuple[pc.Client, pc.Welcome]:
    token = pc.mint_token(plan.secret, room=p.room, player=p.player)
    client = await pc.connect(plan.url, token, reconnect=False, protocol=plan.protocol)
    clients.append(client)  # closed at the end, whatever happens next
    return client, await client.join(p.room, p.player)


async def _main(plan: WorkerPlan) -> WorkerResult:
    out = WorkerResult()
    clients: list[pc.Client] = []
    receivers: list[_Receiver] = []
    tasks: list[asyncio.Task[None]] = []
    drawn: set[str] = set()  # rooms with a drawing receiver in this process
    try:
        joined = await asyncio.gather(*(_join(plan, p, clients) for p in plan.players))
        for p, (client, welcome) in zip(plan.players, joined, strict=True):
            me = welcome.player
            out.welcome = {"lookahead_frames": welcome.lookahead_frames,
                           "rate_hz": welcome.rate_hz, "version": client.version}  # fmt: skip
            out.members[me] = p.room
            draws = plan.draw_all or p.room not in drawn  # the first of its room here
            drawn.add(p.room)
            receiver = _Receiver(client, me, plan.display_hz, draws)
            receivers.append(receiver)
            captures = out.captures.setdefault(me, {})
            tasks.append(asyncio.create_task(_read(client, receiver, out)))
            tasks.append(asyncio.create_task(_stream(client, plan, p, captures)))
        display = asyncio.create_task(_display(receivers, plan, out))
        pending: set[asyncio.Task[None]] = {display, *tasks}
        while display in pending:  # a player's session that ends early is a failure
            done, pending = await asyncio.wait(pending, return_when=asyncio.FIRST_COMPLETED)
            for task in done:
                if not task.cancelled() and task.exception() is not None:
                    out.failures.append(repr(task.exception()))
    finally:
        for task in tasks:
            task.cancel()
        for c in clients:
            with contextlib.suppress(Exception):
                await c.close()
        await asyncio.gather(*tasks, return_exceptions=True)
    for r in sorted(receivers, key=lambda r: not r.draws):  # the drawing players first
        out.displayed.extend((d.sender, d.seq, d.t, d.received, d.shown) for d in r.displayed)
        out.drawn += len(r.displayed) if r.draws else 0
        out.waiting.extend(r.watch.waiting())
        out.jumps_m.extend(r.jumps.jumps_m)
    return out


def run_worker(plan: WorkerPlan) -> WorkerResult:
    """Run ``plan`` in this process (the entry point of a client process)."""
    return asyncio.run(_main(plan))
