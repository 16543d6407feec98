"""The hub (pure): every connection's session and outbox, the rooms, the engine inbox.

Data path through the hub::

    bytes --decode--> Session.handle --action--> Hub
        frames      -> newest frame per player (latest wins) -> take_tick_input()
        join/leave  -> Rooms, presence to the room's audience, engine add/remove ops
        selector, calibrate, kick -> engine ops / ending another connection
    TickOutput (encoded poses, stale/active) -> deliver() -> each audience's Outbox
                                                     + bus: one batch per room
    bus (other nodes' joins, leaves, batches) -> remote_*() -> each audience's Outbox

The hub decides, the asyncio shell (:mod:`posecast.service.app`) only moves bytes:
after each call it wakes the writers in :meth:`pop_dirty` and aborts the sockets in
:meth:`pop_aborts`. A connection whose outbox is :attr:`Outbox.closed` is closed by
its writer once the final message is out. Nothing here blocks or reads a clock.

Other nodes (``docs/scale-out.md``) reach the hub only through its :class:`Bus`: the
hub tells the bus which rooms it has an audience in, who joined and left here, and
each tick's poses per room; the bus calls the ``remote_*`` methods (the
:class:`~posecast.service.bus.BusSink` side) with what the other nodes did. Remote
players are members of a room (``welcome``, presence, capacity) but no audience.
"""

from __future__ import annotations

import logging
import secrets
import zlib
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

from posecast.auth.tokens import Claims, ReplayGuard
from posecast.engine.engine import TrackerFrame
from posecast.errors import (
    MalformedError,
    NotFoundError,
    ProtocolError,
    ReplacedError,
    RoomFullError,
    SlowConsumerError,
    TimedOutError,
)
from posecast.protocol.codec import decode, encode
from posecast.protocol.messages import (
    PROTOCOL_VERSION,
    Bye,
    Error,
    Member,
    Message,
    Presence,
    Welcome,
)
from posecast.service.bus import Bus, MemoryBus
from posecast.service.config import ServerConfig
from posecast.service.metrics import Metrics
from posecast.service.outbox import Outbox
from posecast.service.ratelimit import TokenBucket
from posecast.service.remote import RemoteRooms
from posecast.service.rooms import Rooms
from posecast.service.session import (
    Action,
    CalibrateIn,
    FrameIn,
    Join,
    KickIn,
    Leave,
    Phase,
    Reply,
    SelectorIn,
    Session,
)
from posecast.service.ticker import EngineOp, TickInput, TickOutput

log = logging.getLogger("posecast.service")
_DROP_REASON = {"OUT_OF_ORDER": "out_of_order", "DUPLICATE": "duplicate", "RATE_LIMITED": "rate"}
SHUTDOWN_REASON = "SERVER_SHUTDOWN"  # bye.reason and close reason on shutdown


@dataclass
class Conn:
    session: Session
    outbox: Outbox
    errors: TokenBucket  # budget of non-fatal error replies (the rest are only counted)
    replaced: bool = False  # a newer connection of the same player took its place


class Hub:
    def __init__(
        self,
        cfg: ServerConfig,
        metrics: Metrics,
        wall_offset_s: float = 0.0,
        bus: Bus | None = None,
    ) -> None:
        """``now`` everywhere is server time (monotonic seconds, what ``pose.t`` carries);
        ``wall_offset_s`` turns it into Unix time for token expiry. Without a ``bus``
        the hub is one embedded node."""
        self.cfg = cfg
        self.wall_offset_s = wall_offset_s
        self.metrics = metrics
        self.limits = cfg.limits()
        self.rooms = Rooms(cfg.max_players_per_room, cfg.max_watchers_per_room, cfg.max_rooms)
        self.replay = ReplayGuard(cfg.replay_cache)
        self.conns: dict[int, Conn] = {}
        self.by_player: dict[str, int] = {}  # connection id of each joined id
        self._next_conn = 0
        self._ops: list[EngineOp] = []
        self._latest: dict[str, TrackerFrame] = {}
        self._dirty: set[int] = set()
        self._aborts: set[int] = set()
        self.shutting_down = False
        self._superseded = metrics.frames_dropped.labels("superseded")  # hot path: bind once
        self.bus = bus or MemoryBus(clock=lambda: 0.0)
        self.bus.attach(self)
        self.remote = RemoteRooms()
        self._watched: set[str] = set()  # rooms the bus delivers to this node

    # --- connections ------------------------------------------------------------------

    def connect(self, ip: str, now: float) -> int:
        self._next_conn += 1
        conn = self._next_conn
        session = Session(conn, ip, self.cfg, opened_at=now, wall_offset_s=self.wall_offset_s)
        budget = TokenBucket(self.cfg.error_rate_hz, self.cfg.error_rate_hz)
        self.conns[conn] = Conn(session, Outbox(self.cfg.reliable_queue), budget)
        self.metrics.connections.labels("pending").inc()
        return conn

    def receive(self, conn: int, data: bytes | str, now: float) -> None:
        """One WebSocket message from ``conn``; every outcome lands in outboxes."""
        c = self.conns.get(conn)
        if c is None or c.session.phase is Phase.CLOSED:
            return
        self.metrics.bytes_in.inc(len(data))
        if isinstance(data, str):  # the spec closes these with 1003 (unsupported data)
            exc = MalformedError("posecast v1 uses binary WebSocket messages only")
            self.metrics.errors.labels(exc.code).inc()
            self._end(c, now, final=Error.from_exception(exc), close_code=1003)
            return
        try:
            action = c.session.handle(decode(data, limits=self.limits), now)
            if action is not None:
                self._apply(c, action, now)
        except ProtocolError as exc:
            self._refuse(c, exc, now)

    def disconnect(self, conn: int, now: float) -> None:
        """The socket is gone (after any close): forget the connection."""
        c = self.conns.get(conn)
        if c is None:
            return
        self._end(c, now, final=None)
        del self.conns[conn]
        self.metrics.connections.labels(c.session.role or "pending").dec()

    def outbox(self, conn: int) -> Outbox | None:
        c = self.conns.get(conn)
        return None if c is None else c.outbox

    def pop_dirty(self) -> set[int]:
        out, self._dirty = self._dirty, set()
        return out

    def pop_aborts(self) -> set[int]:
        out, self._aborts = self._aborts, set()
        return out

    # --- what sessions ask for --------------------------------------------------------

    def _apply(self, c: Conn, action: Action, now: float) -> None:
        s = c.session
        if isinstance(action, FrameIn):
            if self._latest.get(s.player) is not None:
                self._superseded.inc()
            self._latest[s.player] = action.frame
            self.metrics.frames_in.inc()
        elif isinstance(action, Join):
            self._join(c, action, now)
        elif isinstance(action, Reply):
            self._send(c, action.message, now)
        elif isinstance(action, Leave):
            self._end(c, now, final=Bye(reason="bye"), burn=True)
        elif isinstance(action, CalibrateIn):
            self._ops.append(EngineOp("calibration", s.player, calibration=action.calibration))
        elif isinstance(action, SelectorIn):
            self._watched_player(s, action.player)
            self._ops.append(EngineOp("selector", action.player, selector=action.selector))
        elif isinstance(action, KickIn):
            target = self.conns[self._watched_player(s, action.player)]
            kicked = Error("KICKED", action.reason[: self.limits.max_text_bytes], True)
            log.info("kick", extra={"player": action.player, "by": s.player})
            self._end(target, now, final=kicked, burn=True)

    def _watched_player(self, s: Session, player: str) -> int:
        room = self.rooms.room_of(player)
        if room is None or room not in s.rooms or player not in self.by_player:
            raise NotFoundError(f"no player {player!r} in a room you watch", field="player")
        return self.by_player[player]

    def _join(self, c: Conn, join: Join, now: float) -> None:
        claims, room = join.claims, join.rooms[0]
        self.replay.check(claims, now + self.wall_offset_s)
        old = self.conns.get(self.by_player.get(claims.player, -1))
        takeover = (
            old is not None
            and claims.role == "player"
            and old.session.role == "player"
            and self.rooms.room_of(claims.player) == room
            and old.session.layout == join.layout
        )
        if not takeover:  # ROOM_FULL before anyone is displaced
            if claims.role == "player":
                self.rooms.check_join(room, as_player=True)
                if (
                    len(self.rooms.members(room)) + self.remote.count(room)
                    >= self.limits.max_players
                ):
                    raise RoomFullError(f"room {room!r} is full across nodes", field="room")
            else:
                self.rooms.check_join(room, join.rooms[1:], as_player=False)
        if old is not None:
            # A takeover keeps the player in its room and the engine; otherwise (another
            # role or room) the old connection leaves first: presence, engine removal.
            old.replaced = takeover
            replaced = Error.from_exception(ReplacedError("the same player joined again"))
            self._end(old, now, final=replaced)
        c.session.joined(join)
        self.by_player[claims.player] = c.session.conn
        self.metrics.connections.labels("pending").dec()
        self.metrics.connections.labels(claims.role).inc()
        if claims.role == "player" and not takeover:
            moved = self.remote.get(room, claims.player)
            if moved is not None:  # it was in this room on a node that failed: now here
                self.remote.leave(room, claims.player, moved.node, now)
            self.rooms.add_player(room, claims.player, join.hello.name)
            seed = zlib.crc32(claims.player.encode())
            self._ops.append(EngineOp("add", claims.player, seed=seed, layout=c.session.layout))
            self.bus.joined(room, claims.player, join.hello.name)
            join_msg = Presence("join", room, claims.player, join.hello.name)
            self._to_room(room, join_msg, now, skip=claims.player)
        elif claims.role != "player":
            self.rooms.add_watcher(join.rooms, claims.player)
        self._send(c, self._welcome(c.session, self._members(room), now), now)
        for extra in join.rooms[1:]:  # a backend learns who is in the rooms it watches
            for m in self._members(extra):
                self._send(c, Presence("join", extra, m.player, m.name), now)
        self._gauges()
        log.info(
            "join",
            extra={"player": claims.player, "role": claims.role, "room": room,
                   "takeover": takeover, "ip": c.session.ip},
        )  # fmt: skip

    def _welcome(self, s: Session, members: tuple[Member, ...], now: float) -> Welcome:
        return Welcome(
            version=PROTOCOL_VERSION,
            player=s.player,
            session=secrets.token_hex(8),
            role=s.role,
            room=s.rooms[0],
            t=now,
            rate_hz=self.cfg.tick_hz,
            lookahead_frames=self.cfg.lookahead,
            members=members[: self.limits.max_players],  # a cross-node race can overfill
            limits=self.limits,
        )

    # --- endings and errors -----------------------------------------------------------

    def _refuse(self, c: Conn, exc: ProtocolError, now: float) -> None:
        self.metrics.errors.labels(exc.code).inc()
        if exc.code in _DROP_REASON:
            self.metrics.frames_dropped.labels(_DROP_REASON[exc.code]).inc()
        err = Error.from_exception(exc)
        if len(err.message.encode()) > self.limits.max_text_bytes:
            err = Error(err.code, err.message[: self.limits.max_text_bytes // 4], err.fatal,
                        err.field, err.ref_seq)  # fmt: skip
        if exc.fatal:
            log.info("refused", extra={"code": exc.code, "ip": c.session.ip, "detail": exc.message})
            self._end(c, now, final=err)
        elif c.errors.allow(now):
            self._send(c, err, now)

    def _end(
        self,
        c: Conn,
        now: float,
        *,
        final: Message | None,
        burn: bool = False,
        close_code: int | None = None,
    ) -> None:
        """End ``c``'s session once: final message, leave rooms and engine, burn the jti."""
        s = c.session
        if s.phase is Phase.CLOSED:
            return
        was_joined = s.phase is Phase.JOINED
        s.close()
        if final is not None:
            code, reason = _close_code(final)
            c.outbox.put_final(encode(final), now, close_code or code, reason)
            self._dirty.add(s.conn)
        if not was_joined:
            return
        if burn and s.claims is not None:
            self.replay.end(s.claims, now + self.wall_offset_s)
            self.bus.burned(s.claims.jti, s.claims.exp)
        drift = s.clock.drift_ppm
        if drift is not None:
            self.metrics.clock_drift.observe(abs(drift))
        log.info(
            "leave",
            extra={"player": s.player, "role": s.role, "frames": s.frames,
                   "offset_s": s.clock.offset_s, "drift_ppm": drift, "replaced": c.replaced},
        )  # fmt: skip
        if c.replaced or self.by_player.get(s.player) != s.conn:
            return
        del self.by_player[s.player]
        played = self.rooms.remove(s.player)
        if played is not None:
            self._latest.pop(s.player, None)
            self._ops.append(EngineOp("remove", s.player))
            self.bus.left(played, s.player)
            if not self.shutting_down:
                self._to_room(played, Presence("leave", played, s.player, s.name), now)
        self._gauges()

    def check_timeouts(self, now: float) -> None:
        """Hello and idle timeouts, and slow consumers; call about once a tick."""
        for c in list(self.conns.values()):
            s, box = c.session, c.outbox
            if box.overflowed or box.stalled_for(now) > self.cfg.slow_consumer_s:
                if s.phase is not Phase.CLOSED:
                    self._refuse(c, SlowConsumerError("the client is not reading"), now)
                self._aborts.add(s.conn)
            elif s.phase is Phase.AWAIT_HELLO and now - s.opened_at > self.cfg.hello_timeout_s:
                self._refuse(c, TimedOutError("no hello in time"), now)
            elif (
                s.phase is Phase.JOINED
                and s.role == "player"  # watchers may stay silent: WebSocket pings keep them
                and now - s.last_message_at > self.cfg.idle_timeout_s
            ):
                self._refuse(c, TimedOutError("no message in time"), now)

    def shutdown(self, now: float) -> None:
        """Say ``bye`` to everyone (and nothing else); the writers flush and close."""
        self.shutting_down = True
        for c in list(self.conns.values()):
            self._end(c, now, final=Bye(reason=SHUTDOWN_REASON))

    # --- the tick ---------------------------------------------------------------------

    def take_tick_input(self) -> TickInput:
        ops, self._ops = self._ops, []
        frames, self._latest = self._latest, {}
        return TickInput(ops, frames)

    def deliver(self, out: TickOutput, now: float) -> None:
        """Route one tick's poses to their rooms' audiences, and stale/active presence."""
        superseded = 0
        batches: dict[str, tuple[list[tuple[str, bytes]], list[bytes]]] = {}
        for player, data in out.poses:
            room = self.rooms.room_of(player)
            if room is None:
                continue  # left while the tick ran
            batches.setdefault(room, ([], []))[0].append((player, data))
            superseded += self._pose_to_room(room, player, data, now)
        for ev in out.events:
            room = self.rooms.room_of(ev.player)
            if room is not None:
                name = self.rooms.name_of(ev.player)
                data = encode(Presence(ev.kind, room, ev.player, name))
                batches.setdefault(room, ([], []))[1].append(data)
                self._bytes_to_room(room, data, now)
        for room, (poses, events) in batches.items():
            self.bus.publish(room, poses, events)  # ONE message per room per tick
        m = self.metrics
        if superseded:
            m.poses_superseded.inc(superseded)
        m.tick_seconds.observe(out.seconds)
        m.batch_size.observe(out.batch)
        if out.transitions:
            m.transitions.inc(out.transitions)

    # --- other nodes: the BusSink side (posecast.service.bus) ----------------------------

    def remote_join(self, room: str, player: str, name: str, node: str, now: float) -> None:
        local = self.conns.get(self.by_player.get(player, -1))
        if local is not None and local.session.role == "player":
            # The same player joined on another node (a reconnect through the balancer
            # landed elsewhere): that one wins, as a takeover does on one node.
            replaced = ReplacedError("the same player joined on another node")
            self._end(local, now, final=Error.from_exception(replaced))
        if room in self._watched and self.remote.join(room, player, node, name, now):
            self._to_room(room, Presence("join", room, player, name), now)
            self._gauges()

    def remote_leave(self, room: str, player: str, node: str, now: float) -> None:
        gone = self.remote.leave(room, player, node, now)
        if gone is not None and self.rooms.room_of(player) != room:
            self._to_room(room, Presence("leave", room, player, gone.name), now)
            self._gauges()

    def remote_tick(
        self,
        room: str,
        node: str,
        poses: Sequence[tuple[str, bytes]],
        events: Sequence[bytes],
        now: float,
    ) -> None:
        unknown = superseded = 0
        for player, data in poses:
            m = self.remote.get(room, player)
            if m is None or m.node != node:
                unknown += 1  # not (yet) a member here: its join or the snapshot comes first
                continue
            superseded += self._pose_to_room(room, player, data, now)
        for data in events:
            self._bytes_to_room(room, data, now)
        if unknown:
            self.metrics.bus_dropped.labels("unknown_player").inc(unknown)
        if superseded:
            self.metrics.poses_superseded.inc(superseded)

    def remote_snapshot(
        self,
        room: str,
        live: Mapping[str, tuple[str, str]],
        issued_at: float,
        now: float,
        keep: bool = False,
    ) -> None:
        """Reconcile ``room``'s remote members with ``live`` (player -> (node, name)).
        ``keep``: add, never remove (a read that other nodes may not have refilled
        yet, e.g. just after Redis came back empty)."""
        if room not in self._watched:
            return
        r = self.rooms.rooms.get(room)
        local = r.players if r is not None else {}
        others = {p: v for p, v in live.items() if p not in local}
        if keep:
            for m in self.remote.members(room):
                held = self.remote.get(room, m.player)
                if held is not None and m.player not in others:
                    others[m.player] = (held.node, m.name)
        joined, left = self.remote.snapshot(room, others, issued_at)
        for m in left:
            if m.player not in local:  # one that moved here left the remote view only
                self._to_room(room, Presence("leave", room, m.player, m.name), now)
        for m in joined:
            self._to_room(room, Presence("join", room, m.player, m.name), now)
        if joined or left:
            self._gauges()

    def remote_lost(self, now: float) -> None:
        """The bus has been down past the node TTL: remote players count as gone."""
        for room in self.remote.rooms:
            self.remote_snapshot(room, {}, float("inf"), now)

    def remote_burn(self, jti: str, exp: int, now: float) -> None:
        self.replay.end(Claims("", "", "", 0, exp, jti), now + self.wall_offset_s)

    def local_rooms(self) -> dict[str, dict[str, str]]:
        return {name: dict(r.players) for name, r in self.rooms.rooms.items()}

    # --- sending ------------------------------------------------------------------------

    def _send(self, c: Conn, msg: Message, now: float) -> None:
        c.outbox.put_reliable(encode(msg), now)  # overflow: check_timeouts cuts it off
        self._dirty.add(c.session.conn)

    def _to_room(self, room: str, msg: Message, now: float, skip: str | None = None) -> None:
        self._bytes_to_room(room, encode(msg), now, skip)

    def _bytes_to_room(self, room: str, data: bytes, now: float, skip: str | None = None) -> None:
        for member in self.rooms.audience(room):
            conn = self.by_player.get(member)
            if member != skip and conn is not None:
                self.conns[conn].outbox.put_reliable(data, now)
                self._dirty.add(conn)

    def _pose_to_room(self, room: str, player: str, data: bytes, now: float) -> int:
        superseded = 0
        for member in self.rooms.audience(room):
            conn = self.by_player.get(member)
            if conn is not None:
                superseded += self.conns[conn].outbox.put_pose(player, data, now)
                self._dirty.add(conn)
        return superseded

    def _members(self, room: str) -> tuple[Member, ...]:
        return self.rooms.members(room) + self.remote.members(room)

    def _gauges(self) -> None:
        self.metrics.players.set(self.rooms.player_count)
        self.metrics.rooms.set(len(self.rooms.rooms))
        rooms = set(self.rooms.rooms)
        new, gone, self._watched = rooms - self._watched, self._watched - rooms, rooms
        for room in gone:
            self.bus.unwatch(room)
            self.remote.drop_room(room)
        for room in new:
            self.bus.watch(room)  # may report the room's remote members at once
        self.metrics.remote_players.set(self.remote.total)


def _close_code(final: Message) -> tuple[int, str]:
    """Close code and reason after ``final`` (``proto/README.md``, Transport): 1000
    after ``bye``, 1001 for a shutdown, 1011 for INTERNAL, 1008 for other errors."""
    if isinstance(final, Bye):
        return (1001 if final.reason == SHUTDOWN_REASON else 1000), final.reason or ""
    if isinstance(final, Error):
        return {"SERVER_SHUTDOWN": 1001, "INTERNAL": 1011}.get(final.code, 1008), final.code
    return 1000, ""
