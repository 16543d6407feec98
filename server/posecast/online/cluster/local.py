"""The ``local`` bus backend: a worker process's link to its node's relay.

``posecast serve --workers N`` runs N serving processes; without ``--redis`` each
one's hub talks to the others through :class:`LocalBus`, over the supervisor's
:class:`~posecast.online.cluster.relay.Relay` (a Unix-domain socket). With ``--redis``
each worker is a node of the Redis bus, and keeps a :class:`RelayLink` only for the
node's merged ``/metrics`` and to notice that its supervisor is gone.

Nothing here is awaited by the tick: the hub's calls write frames to the link and
return; a pose batch is dropped (``posecast_bus_dropped_total{reason="superseded"}``)
rather than queued when the relay is that far behind. What arrives is handed to the
sink as a batch (every complete frame of one read, then :attr:`Bus.after` once), so
the remote poses of several rooms leave for the clients in one write each.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
from collections.abc import Callable

import msgpack

from posecast.online.cluster.bus import Bus, BusMessage, decode_message, deliver, encode_message
from posecast.online.cluster.relay import (
    MAX_BACKLOG_BYTES,
    SCRAPE_TIMEOUT_S,
    FrameReader,
    Op,
    frame,
    metrics_payload,
    scrape_id,
)
from posecast.online.metrics import Metrics
from posecast.online.protocol.pose_out import PoseOut

log = logging.getLogger("posecast.bus")


class RelayLink:
    """One worker's connection to the relay: frames out, frames in (to ``on_frame``),
    the relay's ``SCRAPE`` answered with ``render()``, and the node's merged scrape
    asked for (:meth:`scrape`). ``lost`` is called once when the connection ends."""

    def __init__(
        self,
        path: str,
        node: str,
        label: str,
        *,
        render: Callable[[], bytes],
        lost: Callable[[], None] = lambda: None,
    ) -> None:
        self.path, self.node, self.label = path, node, label
        self.render, self.lost = render, lost
        self.on_frame: Callable[[list[tuple[Op, str, bytes]]], None] = lambda frames: None
        self._writer: asyncio.StreamWriter | None = None
        self._reader_task: asyncio.Task[None] | None = None
        self._asks: dict[int, asyncio.Future[bytes]] = {}
        self._next = 0
        self.connected = False

    async def connect(self) -> None:
        reader, self._writer = await asyncio.open_unix_connection(self.path)
        self.connected = True
        self.send(Op.HELLO, "", msgpack.packb([self.node, self.label], use_bin_type=True))
        self._reader_task = asyncio.create_task(self._read(reader), name="posecast-relay-link")

    async def close(self) -> None:
        if self._writer is not None:
            with contextlib.suppress(ConnectionError, RuntimeError):
                self._writer.write_eof()  # everything written so far reaches the relay
            self._writer.close()
        if self._reader_task is not None:
            self._reader_task.cancel()
            with contextlib.suppress(asyncio.CancelledError):
                await self._reader_task

    @property
    def backlog(self) -> int:
        w = self._writer
        return 0 if w is None else w.transport.get_write_buffer_size()

    def send(self, op: Op, room: str = "", payload: bytes = b"") -> bool:
        """Write one frame; ``False`` when the link is down (nothing was sent)."""
        w = self._writer
        if not self.connected or w is None or w.is_closing():
            return False
        w.write(frame(op, room, payload))
        return True

    async def scrape(self, timeout_s: float = 2 * SCRAPE_TIMEOUT_S) -> bytes | None:
        """The whole node's metrics (every worker's and the supervisor's, merged by the
        relay), or ``None`` when the relay is down or does not answer in time."""
        self._next += 1
        ident = self._next
        fut: asyncio.Future[bytes] = asyncio.get_running_loop().create_future()
        self._asks[ident] = fut
        try:
            if not self.send(Op.SCRAPE, "", metrics_payload(ident, b"")):
                return None
            return await asyncio.wait_for(fut, timeout_s)
        except TimeoutError:
            return None
        finally:
            self._asks.pop(ident, None)

    async def _read(self, reader: asyncio.StreamReader) -> None:
        frames = FrameReader()
        try:
            while data := await reader.read(1 << 18):
                batch: list[tuple[Op, str, bytes]] = []
                for op, room, payload in frames.feed(data):
                    if op is Op.SCRAPE:
                        self.send(
                            Op.METRICS, "", metrics_payload(scrape_id(payload), self.render())
                        )
                    elif op is Op.METRICS:
                        fut = self._asks.get(scrape_id(payload))
                        if fut is not None and not fut.done():
                            fut.set_result(payload[4:])
                    else:
                        batch.append((op, room, payload))
                if batch:
                    self.on_frame(batch)
        except (ConnectionError, ValueError) as exc:
            log.warning("relay link broken", extra={"why": str(exc)})
        finally:
            self.connected = False
            self.lost()


class LocalBus(Bus):
    """The ``local`` backend: the other workers of this node, through the relay."""

    unavailable = "relay unavailable"

    def __init__(self, link: RelayLink, metrics: Metrics, *, clock: Callable[[], float]) -> None:
        super().__init__(link.node)
        self.link, self.metrics, self.clock = link, metrics, clock
        link.on_frame = self._receive
        self._issued: dict[str, float] = {}  # room -> when its WATCH was sent
        self._superseded = metrics.bus_dropped.labels("superseded")
        self._disconnected = metrics.bus_dropped.labels("disconnected")
        self._undecodable = metrics.bus_dropped.labels("undecodable")
        self._out_ticks = metrics.bus_messages.labels("out", "tick")
        self._in_ticks = metrics.bus_messages.labels("in", "tick")

    @property
    def healthy(self) -> bool:
        return self.link.connected

    @property
    def status(self) -> str:
        return "ok" if self.link.connected else "relay unavailable"

    async def start(self) -> None:
        self.metrics.bus_connected.set(int(self.link.connected))

    async def stop(self) -> None:
        """The leaves the shutdown queued are written; then the link closes."""
        await self.link.close()
        self.metrics.bus_connected.set(0)

    def watch(self, room: str) -> None:
        self._issued[room] = self.clock()
        self.link.send(Op.WATCH, room)

    def unwatch(self, room: str) -> None:
        self._issued.pop(room, None)
        self.link.send(Op.UNWATCH, room)

    def joined(self, room: str, player: str, name: str) -> None:
        self._announce(Op.JOIN, room, BusMessage("join", self.node, player, name))

    def left(self, room: str, player: str) -> None:
        self._announce(Op.LEAVE, room, BusMessage("leave", self.node, player))

    def burned(self, jti: str, exp: int) -> None:
        self._announce(Op.BURN, "", BusMessage("burn", self.node, jti, exp=exp))

    def publish(self, room: str, poses: list[PoseOut], events: list[bytes]) -> None:
        if not self.link.connected:
            self._disconnected.inc()
            return
        if self.link.backlog > MAX_BACKLOG_BYTES:
            self._superseded.inc()  # the next tick's batch replaces it
            return
        m = BusMessage("tick", self.node, poses=tuple(poses), events=tuple(events))
        self.link.send(Op.TICK, room, encode_message(m))
        self._out_ticks.inc()

    def _announce(self, op: Op, room: str, m: BusMessage) -> None:
        if self.link.send(op, room, encode_message(m)):
            self.metrics.bus_messages.labels("out", m.kind).inc()
        else:
            self._disconnected.inc()

    def _receive(self, frames: list[tuple[Op, str, bytes]]) -> None:
        sink = self.sink
        if sink is None:
            return
        for op, room, payload in frames:
            now = self.clock()
            if op is Op.SNAPSHOT:
                issued = self._issued.get(room)
                if issued is None:
                    continue  # unwatched meanwhile
                raw = msgpack.unpackb(payload, raw=False)
                live = {str(p): (str(v[0]), str(v[1])) for p, v in raw.items()}
                sink.remote_snapshot(room, live, issued, now)
                continue
            m = decode_message(payload)
            if m is None:
                self._undecodable.inc()
                continue
            if m.node == self.node:
                continue
            if m.kind == "tick":
                self._in_ticks.inc()
            else:
                self.metrics.bus_messages.labels("in", m.kind).inc()
            deliver(sink, room, m, now)
        self.after()
