"""The ``local`` bus (posecast.online.cluster.local) and the node's relay
(posecast.online.cluster.relay): two hubs on two LocalBus links to one relay, on a
temporary Unix-domain socket in one process, as the workers of ``posecast serve
--workers 2`` share rooms. The same scenarios as the in-memory bus's
(``test_memory.py``), plus what only processes have: a worker's link closing (it
died), and the node's merged scrape."""

from __future__ import annotations

import asyncio
import tempfile
import time
from collections.abc import AsyncIterator, Callable, Coroutine
from contextlib import asynccontextmanager
from pathlib import Path
from typing import Any

import pytest

from posecast.online.cluster.bus import BusMessage, encode_message
from posecast.online.cluster.local import LocalBus, RelayLink
from posecast.online.cluster.relay import FrameReader, Op, Relay, frame
from posecast.online.core.hub import Hub
from posecast.online.metrics import Metrics, merge_expositions
from posecast.online.protocol import decode, encode
from posecast.online.protocol.messages import Bye, Error, Hello, Message, Pose, Presence, Welcome
from posecast.online.shell.ticker import TickOutput
from posecast.testing.poses import of_message
from posecast.testing.serve import parse_metrics
from tests.online.cluster.test_memory import make_pose
from tests.online.conftest import make_cfg, token

pytestmark = pytest.mark.timeout(30)


def run(coro: Coroutine[Any, Any, None]) -> None:
    asyncio.run(coro)


async def until(cond: Callable[[], bool], timeout_s: float = 5.0) -> None:
    deadline = time.monotonic() + timeout_s
    while not cond():
        assert time.monotonic() < deadline, "condition never held"
        await asyncio.sleep(0.005)


async def settled() -> None:
    """Long enough for frames to cross the relay both ways on a busy machine."""
    await asyncio.sleep(0.1)


class Worker:
    """One hub on a LocalBus linked to the relay (what one worker process runs)."""

    def __init__(self, path: str, name: str, label: str, **cfg: Any) -> None:
        self.metrics = Metrics()
        self.link = RelayLink(path, name, label, render=self.metrics.render)
        self.bus = LocalBus(self.link, self.metrics, clock=time.monotonic)
        offset = time.time() - time.monotonic()
        self.hub = Hub(make_cfg(**cfg), self.metrics, wall_offset_s=offset, bus=self.bus)
        self.boxes: dict[int, list[Message]] = {}

    def join(self, player: str, room: str = "r1") -> int:
        conn = self.hub.connect("10.0.0.1", time.monotonic())
        tok = token(room=room, player=player)
        self.hub.receive(conn, encode(Hello(1, tok, room, player.upper())), time.monotonic())
        return conn

    def inbox(self, conn: int) -> list[Message]:
        box = self.hub.outbox(conn)
        assert box is not None
        out = [decode(d) for d in box.take()]
        box.sent(time.monotonic())
        return out

    def tick(self, *players: str, seq: int = 0) -> None:
        out = TickOutput([of_message(make_pose(p, seq)) for p in players])
        self.hub.deliver(out, time.monotonic())


@asynccontextmanager
async def node(**cfg: Any) -> AsyncIterator[tuple[Relay, Worker, Worker]]:
    with tempfile.TemporaryDirectory(prefix="posecast-test-relay-") as tmp:
        relay = Relay(
            str(Path(tmp) / "relay.sock"), own_metrics=lambda: b"", merge=merge_expositions
        )
        await relay.start()
        a, b = Worker(relay.path, "A", "0", **cfg), Worker(relay.path, "B", "1", **cfg)
        await a.link.connect()
        await b.link.connect()
        await until(lambda: len(relay.workers) == 2 and all(w.node for w in relay.workers))
        try:
            yield relay, a, b
        finally:
            await a.bus.stop()
            await b.bus.stop()
            await relay.stop()


def test_frames_split_anywhere_come_out_whole() -> None:
    data = frame(Op.TICK, "room-1", b"x" * 300) + frame(Op.WATCH, "r") + frame(Op.HELLO)
    for cut in (1, 3, 5, 7, 200, len(data) - 1):
        reader = FrameReader()
        got = [*reader.feed(data[:cut]), *reader.feed(data[cut:])]
        assert got == [(Op.TICK, "room-1", b"x" * 300), (Op.WATCH, "r", b""), (Op.HELLO, "", b"")]
    with pytest.raises(ValueError):
        list(FrameReader().feed(b"\xff\xff\xff\xff"))  # 4 GB: refused, never buffered


def test_two_workers_share_a_room_and_other_rooms_see_nothing() -> None:
    async def scenario() -> None:
        async with node() as (relay, a, b):
            pa = a.join("pa")
            await settled()
            (welcome,) = a.inbox(pa)
            assert isinstance(welcome, Welcome)
            pb, other = b.join("pb"), b.join("pc", room="r2")
            await until(lambda: bool(b.hub.remote.total))
            welcome_b, *rest = b.inbox(pb)  # this worker's view; then pa, from the snapshot
            assert isinstance(welcome_b, Welcome) and rest == [Presence("join", "r1", "pa", "PA")]
            await settled()
            assert a.inbox(pa) == [Presence("join", "r1", "pb", "PB")]
            b.inbox(other)

            a.tick("pa", seq=1)
            b.tick("pb", "pc", seq=1)
            await settled()
            assert {m.player for m in b.inbox(pb) if isinstance(m, Pose)} == {"pa", "pb"}
            assert {m.player for m in a.inbox(pa) if isinstance(m, Pose)} == {"pa", "pb"}
            assert all(m.player == "pc" for m in b.inbox(other) if isinstance(m, Pose))
            assert b.metrics.value("posecast_remote_players") == 1

            a.hub.disconnect(pa, time.monotonic())
            await settled()
            assert b.inbox(pb) == [Presence("leave", "r1", "pa", "PA")]
            assert {p: (w.node, n) for p, (w, n) in relay.members["r1"].items()} == {
                "pb": ("B", "PB")
            }

    run(scenario())


def test_a_tick_crosses_only_to_workers_watching_its_room() -> None:
    async def scenario() -> None:
        async with node() as (relay, a, b):
            for p in ("p1", "p2", "p3"):
                a.join(p)
            a.join("q1", room="r2")
            b.join("watcher-of-r1")
            await settled()
            before = relay.counts.forwarded
            a.tick("p1", "p2", "p3", "q1")
            await settled()
            assert relay.counts.forwarded - before == 1  # r1 only: nobody else is in r2
            ticks_in = {"direction": "in", "kind": "tick"}
            assert b.metrics.value("posecast_bus_messages_total", ticks_in) == 1

    run(scenario())


def test_the_same_player_joining_another_worker_replaces_the_first() -> None:
    async def scenario() -> None:
        async with node() as (relay, a, b):
            first, mate = a.join("p"), a.join("mate")
            await settled()
            a.inbox(first)
            a.inbox(mate)
            b.join("p")
            await settled()
            errors = [m for m in a.inbox(first) if isinstance(m, Error)]
            assert [e.code for e in errors] == ["REPLACED"]
            assert a.inbox(mate)[-1] == Presence("join", "r1", "p", "P")  # now it plays on B
            owner, _ = relay.members["r1"]["p"]
            assert owner.node == "B"

    run(scenario())


def test_room_capacity_counts_players_on_every_worker() -> None:
    async def scenario() -> None:
        async with node(max_players_per_room=2) as (_, a, b):
            a.join("p1")
            await settled()
            b.join("p2")
            await settled()
            late = a.join("p3")
            errors = [m for m in a.inbox(late) if isinstance(m, Error)]
            assert [e.code for e in errors] == ["ROOM_FULL"]

    run(scenario())


def test_a_token_burned_on_one_worker_is_refused_on_the_other_and_on_a_new_one() -> None:
    async def scenario() -> None:
        async with node() as (relay, a, b):
            tok = token(room="r1", player="p")
            conn = a.hub.connect("10.0.0.1", time.monotonic())
            a.hub.receive(conn, encode(Hello(1, tok, "r1", "P")), time.monotonic())
            a.hub.receive(conn, encode(Bye("done")), time.monotonic())
            await settled()
            again = b.hub.connect("10.0.0.1", time.monotonic())
            b.hub.receive(again, encode(Hello(1, tok, "r1", "P")), time.monotonic())
            assert [e.code for e in b.inbox(again) if isinstance(e, Error)] == ["UNAUTHENTICATED"]
            # A worker started later (a restart) hears of the burn when it connects.
            c = Worker(relay.path, "C", "2")
            await c.link.connect()
            await settled()
            late = c.hub.connect("10.0.0.1", time.monotonic())
            c.hub.receive(late, encode(Hello(1, tok, "r1", "P")), time.monotonic())
            assert [e.code for e in c.inbox(late) if isinstance(e, Error)] == ["UNAUTHENTICATED"]
            await c.bus.stop()

    run(scenario())


def test_a_dead_workers_players_are_announced_gone_and_its_link_reports_down() -> None:
    """Worker B's link closes without a leave (the process died): the relay drops its
    members and A's players hear ``leave``; A's own link stays up. B's bus, cut off,
    says so (``/readyz`` reads it) and counts what it could not send."""

    async def scenario() -> None:
        async with node() as (relay, a, b):
            lost: list[bool] = []
            b.link.lost = lambda: lost.append(True)
            pa = a.join("pa")
            b.join("pb1")
            b.join("pb2")
            await until(lambda: a.hub.remote.total == 2)
            a.inbox(pa)
            assert b.link._writer is not None
            b.link._writer.transport.abort()  # as the kernel does for a killed process
            await until(lambda: a.hub.remote.total == 0)
            leaves = {m.player for m in a.inbox(pa) if isinstance(m, Presence)}
            assert leaves == {"pb1", "pb2"}
            assert "r1" in relay.members and set(relay.members["r1"]) == {"pa"}
            await until(lambda: bool(lost))
            assert a.bus.healthy and not b.bus.healthy
            b.tick("pb1", seq=2)
            dropped = b.metrics.value("posecast_bus_dropped_total", {"reason": "disconnected"})
            assert dropped == 1

    run(scenario())


def test_one_scrape_merges_every_workers_metrics_with_a_worker_label() -> None:
    async def scenario() -> None:
        async with node() as (relay, a, b):
            relay.own_metrics = lambda: b"# TYPE posecast_workers gauge\nposecast_workers 2.0\n"
            a.join("pa")
            b.join("pb")
            b.join("pc")
            await settled()
            text = await a.link.scrape()
            assert text is not None
            m = parse_metrics(text.decode())
            assert m['posecast_players{worker="0"}'] == 1
            assert m['posecast_players{worker="1"}'] == 2
            assert m['posecast_workers{worker="supervisor"}'] == 2
            # A worker that never answers is left out after the timeout, not waited for.
            stuck = RelayLink(relay.path, "S", "2", render=lambda: b"")
            await stuck.connect()
            assert stuck._reader_task is not None
            stuck._reader_task.cancel()
            await settled()
            t0 = time.monotonic()
            text = await b.link.scrape()
            assert text is not None and time.monotonic() - t0 < 1.5
            assert 'worker="1"' in text.decode() and 'worker="2"' not in text.decode()
            await stuck.close()

    run(scenario())


def test_a_malformed_announcement_is_dropped_by_the_relay() -> None:
    async def scenario() -> None:
        async with node() as (relay, a, b):
            pb = b.join("pb")
            await settled()
            b.inbox(pb)
            a.link.send(Op.JOIN, "r1", b"\xc1 not msgpack")
            a.link.send(Op.JOIN, "r1", encode_message(BusMessage("join", "A", "ok", "OK")))
            await settled()
            assert set(relay.members["r1"]) == {"pb", "ok"}
            assert b.inbox(pb) == [Presence("join", "r1", "ok", "OK")]

    run(scenario())
