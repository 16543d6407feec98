"""The lean load generator: every player of a ramp in one process, as cheap as it gets.

    python benchmarks/lean_clients.py --url ws://127.0.0.1:PORT/ --secret SECRET \\
                                      --room-size 8 [--room-prefix lean] [--protocol 2]

``load.py ramp`` (its default ``--clients lean``) runs this as a subprocess and drives
it over stdin/stdout, one JSON line each way per command (:class:`LeanClients` in
``load_rig.py`` is that side):

* ``{"cmd": "add", "players": N}``: N more players connect and join; rooms are filled
  in order (player ``PREFIX-pI`` is in room ``PREFIX-roomR``, ``R = I // room_size``).
  The answer comes once they have all had their ``welcome`` or failed;
* ``{"cmd": "stats"}``: the counters now (see :meth:`Generator.stats`);
* ``{"cmd": "stop"}``: every player closes; the last answer; the process exits.

Why it is cheap, against ``posecast-sim`` (an SDK ``Client`` per player):

* one asyncio loop and the ``websockets`` library, no SDK session per frame: a single
  60 Hz ticker sends every player's frame in turn;
* frames are **pre-encoded**: each player's motion (the SDK's procedural walk, 10 s
  at 60 Hz, looped; built once per seed up front) is packed once into the bytes that
  follow ``t``; ``seq`` and ``t`` are written as a uint32 and a float64, so that
  they sit at fixed places and a frame is one ``struct.pack`` and a concatenation
  (:class:`FrameCycle`). A uint32 ``seq`` is not canonical (that is its smallest
  int form) but every decoder accepts any int width (``proto/README.md``,
  *Encoding*); the first frame is decoded once with the SDK's codec as a check;
* incoming poses are **counted, never decoded**, as the frames are parsed, skipping
  ``recv()`` and its queue (:class:`CountingConnection`). ``--protocol 2`` (the
  default, what the SDKs speak: they offer ``posecast.v2`` first) gets one ``poses``
  message per tick whose ``data`` is the concatenation of that tick's pose records
  (``proto/README.md``, *Pose records*); they carry no count, so :func:`count_records`
  walks them: a record's avatar id and flags, then a keyframe's fixed 130 bytes or a
  delta's 20 two-bit classes (which give its length), nothing dequantised and no
  reference state kept. A v2 receiver owes the server nothing back (no acks: the
  server keeps each client's reference itself; ``resync`` only after a record it could
  not apply, which a counter never has). ``--protocol 1`` gets one ``pose`` message per
  avatar per tick, recognised by the ten bytes after its map header (the server writes
  ``type`` first: ``a4 "type" a4 "pose"``). Only the rare other messages (presence,
  errors) are unpacked;
* its own CPU is in every ``stats`` answer: ``time.process_time()`` (user + system
  time of this process, all threads) beside ``time.monotonic()``, so a window's
  generator CPU share is their ratio of differences.

The server sends every pose of a room to every member, its sender included, so over
``dt`` seconds a player in a room of ``m`` members at the room's pose rate ``r``
(``welcome.rate_hz``; in v2 at most the client's ``welcome.pose_rate_hz``, 60 here)
should receive ``r * m * dt`` poses (v1 ``pose`` messages, v2 records); ``stats``
gives each player's count, ``m`` (``welcome.members``, then presence
``join``/``leave``) and ``r``.
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import json
import struct
import sys
import time
from dataclasses import dataclass, field
from typing import Any

import msgpack
import numpy as np
from posecast_client.codec import decode
from posecast_client.protocol import SUBPROTOCOLS
from posecast_client.protocol import Frame as FrameMessage
from posecast_client.sources import WalkSource
from posecast_client.tokens import mint_token
from websockets.asyncio.client import ClientConnection, connect
from websockets.exceptions import ConnectionClosed, InvalidStatus
from websockets.frames import Frame, Opcode
from websockets.typing import Subprotocol

RATE_HZ = 60.0  # frames per second per player (hello leaves rate_hz out: 60)
WALK_SEEDS = 16  # distinct walks; player i replays walk i % 16 at its place in the room
WALK_S = 10.0
LATE_RESYNC_S = 0.25  # a ticker this far behind starts its schedule afresh


def _p(value: object) -> bytes:
    out: bytes = msgpack.packb(value, use_bin_type=True)
    return out


# --- frames, pre-encoded --------------------------------------------------------------------

# {"type": "frame", "seq": uint32, "t": float64, "trackers": [...]}: keys in canonical
# order, valid left out (15, all tracked). Only seq and t change from frame to frame.
_HEAD = b"\x84" + _p("type") + _p("frame") + _p("seq") + b"\xce"  # fixmap(4) ... uint32
_SEQ_T = struct.Struct(">I3sd")  # seq, then "t" and the float64 marker, then t
_T_KEY = _p("t") + b"\xcb"
POSE_PREFIX = _p("type") + _p("pose")  # bytes 1..10 of a pose (byte 0: its fixmap header)
# v2: {"type": "poses", "t": float64, "data": bin}, as the server writes it (canonical
# order, t always a float64): data's bin header sits at byte 28.
POSES_PREFIX = b"\x83" + _p("type") + _p("poses") + _p("t") + b"\xcb"  # bytes 0..14
_DATA_KEY = _p("data")  # bytes 23..27


# --- v2 pose records, counted ----------------------------------------------------------------

# A delta's bitstream: per item a 2-bit class, then 3 components of the class's width;
# these are the bits each class takes, the class included (proto/README.md, *Delta*).
_ROOT_BITS = tuple(2 + 3 * w for w in (0, 5, 8, 14))
_ROT_BITS = tuple(2 + 3 * w for w in (0, 4, 7, 12))
_MAX_DELTA_BYTES = 110  # 20 items of the widest class, rounded up to bytes
KEYFRAME_BYTES = 130  # after the flags: seq, root, 19 smallest-three items


def count_records(data: bytes) -> int:
    """The number of pose records in a v2 ``poses.data``: each is walked to its end
    (avatar id, flags, then a keyframe's 130 bytes or a delta's seq step and bitstream),
    nothing else read. Raises ``ValueError`` for records cut short or running over."""
    n = pos = 0
    end = len(data)
    try:
        while pos < end:
            while data[pos] & 0x80:  # the avatar id, LEB128
                pos += 1
            flags = data[pos + 1]
            pos += 2
            if flags & 1:
                pos += KEYFRAME_BYTES
            else:
                acc = int.from_bytes(data[pos + 1 : pos + 1 + _MAX_DELTA_BYTES], "little")
                bit = _ROOT_BITS[acc & 3]
                for _ in range(19):
                    bit += _ROT_BITS[acc >> bit & 3]
                pos += 1 + ((bit + 7) >> 3)
            n += 1
    except IndexError:
        pos = end + 1
    if pos != end:
        raise ValueError("pose records cut short or running over the data")
    return n


def poses_data(message: bytes) -> bytes | None:
    """``data`` of a v2 ``poses`` message, read at its fixed place (the server's
    canonical bytes), else by unpacking; ``None`` for any other message."""
    if message[:15] == POSES_PREFIX and message[23:28] == _DATA_KEY:
        marker = message[28]
        if marker == 0xC4:
            return message[30 : 30 + message[29]]
        if marker == 0xC5:
            return message[31 : 31 + int.from_bytes(message[29:31], "big")]
    try:  # the rare other messages (presence, errors), or poses written another way
        m = msgpack.unpackb(message)
    except ValueError:
        return None  # on_message's unpacking says what is wrong
    if isinstance(m, dict) and m.get("type") == "poses" and isinstance(m.get("data"), bytes):
        return m["data"]
    return None


class FrameCycle:
    """One player's frames, pre-encoded: ``frame(k, seq, t)`` is frame ``k % n`` of the
    motion with that ``seq`` and ``t``, as bytes ready to send."""

    def __init__(self, positions: np.ndarray, orientations: np.ndarray) -> None:
        rows = np.concatenate([positions, orientations], axis=-1)  # (F, 4, 7)
        rows[..., 3:] /= np.linalg.norm(rows[..., 3:], axis=-1, keepdims=True)
        self.tails = [_p("trackers") + _p(r) for r in rows.tolist()]

    def frame(self, k: int, seq: int, t: float) -> bytes:
        tail = self.tails[k % len(self.tails)]
        return _HEAD + _SEQ_T.pack(seq & 0xFFFFFFFF, _T_KEY, t) + tail


def check_frame_bytes(cycle: FrameCycle) -> None:
    """Decode one pre-encoded frame with the SDK's codec: what the patching writes is a
    valid frame with the seq and t it was given (raises otherwise)."""
    msg = decode(cycle.frame(1, 123456, 42.5))
    if not (isinstance(msg, FrameMessage) and msg.seq == 123456 and msg.t == 42.5):
        raise AssertionError(f"pre-encoded frame decodes to {msg!r}")


# --- players --------------------------------------------------------------------------------


class CountingConnection(ClientConnection):
    """A client connection that counts poses as its frames are parsed, instead of
    queueing them for ``recv()``: v1 ``pose`` messages, or the records of v2 ``poses``
    (``malformed`` counts batches whose records do not add up); other messages go to
    ``on_message``.

    It overrides ``process_event``, the method ``ClientConnection`` itself overrides to
    handle the handshake: not public API, checked with websockets 17.4. Were it to stop
    being called, poses would count zero and every ramp step would fail on delivery,
    loudly. Control frames (ping, pong, close) still go the library's way, so the
    server's keepalive pings are answered and closing works as usual.
    """

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        self.poses = 0
        self.malformed = 0
        self.on_message: Any = None  # Callable[[bytes], None], set before hello

    def process_event(self, event: Any) -> None:
        binary = isinstance(event, Frame) and event.opcode is Opcode.BINARY and event.fin
        if not (binary and self.response is not None):  # the handshake, control frames
            super().process_event(event)
        elif event.data[1:11] == POSE_PREFIX:  # v1
            self.poses += 1
        elif (data := poses_data(event.data)) is not None:  # v2
            try:
                self.poses += count_records(data)
            except ValueError:
                self.malformed += 1
        elif self.on_message is not None:
            self.on_message(bytes(event.data))


@dataclass
class Player:
    index: int
    player: str
    room: str
    cycle: FrameCycle
    ws: CountingConnection | None = None
    seq: int = 0
    members: int = 0  # in its room, itself included
    rate_hz: float = RATE_HZ  # the room's pose rate, from welcome
    welcome: asyncio.Future[None] | None = None
    open: bool = False  # joined, and the connection has not closed since
    closed_by_us: bool = False
    lost: bool = False
    errors: list[str] = field(default_factory=list)

    def on_message(self, data: bytes) -> None:
        m = msgpack.unpackb(data)
        kind = m.get("type")
        if kind == "welcome":
            self.rate_hz, self.members = float(m["rate_hz"]), len(m["members"])
            if "pose_rate_hz" in m:  # v2: this client's rate, a divisor of the room's tick
                self.rate_hz = min(self.rate_hz, float(m["pose_rate_hz"]))
            if self.welcome is not None and not self.welcome.done():
                self.welcome.set_result(None)
        elif kind == "presence" and m.get("room") == self.room:
            self.members += {"join": 1, "leave": -1}.get(m.get("event"), 0)
        elif kind == "error":
            self.errors.append(str(m.get("code")))
            if self.welcome is not None and not self.welcome.done():
                self.welcome.set_exception(RuntimeError(f"refused: {m.get('code')}"))


class Generator:
    def __init__(
        self, url: str, secret: str, room_size: int, prefix: str, protocol: int = 2
    ) -> None:
        self.url, self.secret, self.room_size, self.prefix = url, secret, room_size, prefix
        self.protocol = protocol
        self.players: list[Player] = []
        self.streaming: list[Player] = []
        self.failed: dict[str, str] = {}
        self.frames_sent = 0
        self.ticks = 0
        self.late_ticks = 0  # ticks whose frames left more than one period late
        self.stopping = False
        self._watchers: set[asyncio.Task[None]] = set()
        # The walks, built once: building one takes ~70 ms, a stall for every player.
        self.walks = [WalkSource(seconds=WALK_S, seed=s, loop=True) for s in range(WALK_SEEDS)]

    def _cycle(self, i: int, place: int) -> FrameCycle:
        walk = self.walks[i % WALK_SEEDS]
        offset = np.array([(place % 4) * 1.2, 0.0, (place // 4) * 1.2])  # as posecast-sim
        return FrameCycle(walk.positions + offset, walk.orientations)

    async def add(self, n: int, timeout_s: float) -> dict[str, Any]:
        joins = []
        for _ in range(n):
            i = len(self.players)
            place = i % self.room_size
            room = f"{self.prefix}-room{i // self.room_size}"
            p = Player(i, f"{self.prefix}-p{i}", room, self._cycle(i, place))
            self.players.append(p)
            joins.append(asyncio.create_task(self._join(p, timeout_s)))
            await asyncio.sleep(0.01)  # stagger the handshakes a little
        await asyncio.gather(*joins)
        return {"players": len(self.players), "joined": len(self.streaming),
                "failed": self.failed}  # fmt: skip

    async def _join(self, p: Player, timeout_s: float) -> None:
        token = mint_token(self.secret, room=p.room, player=p.player, ttl_s=3600)
        hello = {"type": "hello", "version": self.protocol, "token": token, "room": p.room,
                 "name": f"Lean {p.index}"}  # fmt: skip
        try:
            async with asyncio.timeout(timeout_s):
                ws = await self._connect()
                p.ws, ws.on_message = ws, p.on_message
                p.welcome = asyncio.get_running_loop().create_future()
                await ws.send(_p(hello))
                await p.welcome
        except Exception as exc:
            self.failed[p.player] = repr(exc)
            if p.ws is not None:
                await p.ws.close()
            return
        self.streaming.append(p)
        p.open = True
        watcher = asyncio.create_task(self._watch(p))
        self._watchers.add(watcher)
        watcher.add_done_callback(self._watchers.discard)

    async def _connect(self) -> CountingConnection:
        delay = 0.25
        while True:
            try:
                ws = await connect(
                    self.url,
                    subprotocols=[Subprotocol(SUBPROTOCOLS[self.protocol])],
                    compression=None,
                    max_size=65_536,
                    ping_interval=None,  # the server pings; pongs are answered as usual
                    create_connection=CountingConnection,
                )
                assert isinstance(ws, CountingConnection)
                return ws
            except InvalidStatus as exc:  # 429/503: too many connections, or starting
                if exc.response.status_code not in (429, 503):
                    raise
            await asyncio.sleep(delay)
            delay = min(2 * delay, 4.0)

    async def _watch(self, p: Player) -> None:
        assert p.ws is not None
        await p.ws.wait_closed()
        p.lost = not (self.stopping or p.closed_by_us)
        p.open = False
        self.streaming.remove(p)

    async def tick(self) -> None:
        """Every player's next frame, RATE_HZ times a second, on an absolute schedule."""
        period = 1.0 / RATE_HZ
        start, k = time.monotonic(), 0
        while not self.stopping:
            delay = start + k * period - time.monotonic()
            if delay > 0:
                await asyncio.sleep(delay)
            elif -delay > LATE_RESYNC_S:
                start = time.monotonic() - k * period
            if -delay > period:
                self.late_ticks += 1
            now = time.monotonic()
            for p in tuple(self.streaming):
                assert p.ws is not None
                data = p.cycle.frame(p.seq, p.seq, now)
                p.seq += 1
                with contextlib.suppress(ConnectionClosed):  # _watch notices
                    await p.ws.send(data)
                    self.frames_sent += 1
            self.ticks += 1
            k += 1

    def stats(self) -> dict[str, Any]:
        """Counters now. ``players`` rows: ``[id, room, poses received, room members
        (itself included), the room's pose rate in Hz, connection open]``."""
        rows = [
            [p.player, p.room, p.ws.poses if p.ws else 0, p.members, p.rate_hz, p.open]
            for p in self.players
        ]
        malformed = sum(p.ws.malformed for p in self.players if p.ws is not None)
        return {
            "protocol": self.protocol,
            "t": time.monotonic(),
            "cpu_s": time.process_time(),
            "frames_sent": self.frames_sent,
            "ticks": self.ticks,
            "late_ticks": self.late_ticks,
            "joined": len(self.streaming),
            "connection_losses": sum(p.lost for p in self.players),
            "errors": sum(len(p.errors) for p in self.players) + malformed,
            "error_codes": sorted(
                {c for p in self.players for c in p.errors}
                | ({"MALFORMED_RECORDS"} if malformed else set())
            ),
            "failed": self.failed,
            "players": rows,
        }

    async def stop(self) -> dict[str, Any]:
        self.stopping = True
        for p in self.players:
            p.closed_by_us = True
        await asyncio.gather(*(p.ws.close() for p in self.players if p.ws is not None))
        return self.stats()


# --- the control channel ----------------------------------------------------------------


def _answer(obj: dict[str, Any]) -> None:
    sys.stdout.write(json.dumps(obj, separators=(",", ":")) + "\n")
    sys.stdout.flush()


async def run(args: argparse.Namespace) -> None:
    gen = Generator(args.url, args.secret, args.room_size, args.room_prefix, args.protocol)
    check_frame_bytes(gen._cycle(0, 0))
    loop = asyncio.get_running_loop()
    reader = asyncio.StreamReader()
    await loop.connect_read_pipe(lambda: asyncio.StreamReaderProtocol(reader), sys.stdin)
    ticker = asyncio.create_task(gen.tick())
    _answer({"ready": True})
    while line := await reader.readline():  # EOF: the parent has gone, stop too
        cmd = json.loads(line)
        if cmd["cmd"] == "add":
            _answer(await gen.add(int(cmd["players"]), float(cmd.get("timeout_s", 60.0))))
        elif cmd["cmd"] == "stats":
            _answer(gen.stats())
        elif cmd["cmd"] == "stop":
            break
        else:
            _answer({"error": f"unknown command {cmd['cmd']!r}"})
    final = await gen.stop()
    ticker.cancel()
    with contextlib.suppress(asyncio.CancelledError):
        await ticker
    _answer(final)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--url", required=True, help="the server, ws://HOST:PORT/")
    ap.add_argument("--secret", required=True, help="the server's token secret")
    ap.add_argument("--room-size", type=int, default=4, help="players per room (4)")
    ap.add_argument("--room-prefix", default="lean", help="rooms are PREFIX-room0, ... (lean)")
    ap.add_argument(
        "--protocol", type=int, choices=(1, 2), default=2,
        help="2: posecast.v2, pose records in one poses message per tick, as the SDKs; "
        "1: posecast.v1, a pose message per avatar per tick (2)",
    )  # fmt: skip
    asyncio.run(run(ap.parse_args(argv)))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
