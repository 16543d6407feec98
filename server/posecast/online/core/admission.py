"""Admission (pure): connections open, messages are handled, sessions join and end.

::

    bytes --decode--> Session.handle --action--> Admission
        hello        -> replay guard, capacity, takeover -> Rooms, welcome, presence
        frame        -> EngineInbox (a short queue per player)
        calibrate, selector -> EngineInbox; kick -> ending another connection
        bye / fatal error / timeout -> one ending: final message, rooms, engine, bus

Every outcome lands in outboxes (:class:`~posecast.online.core.connections.Connections`).
A refused message answers with its error code; anything else that goes wrong while
a message is handled is a bug: it is logged with its traceback and answered
``INTERNAL`` (non-fatal), and the server goes on. A client IP whose connections keep
ending in fatal errors spends its :class:`~posecast.online.core.ratelimit.FatalBudget`
and is turned away at the HTTP upgrade (:meth:`Admission.admits`).
"""

from __future__ import annotations

import logging
import secrets
import zlib
from collections.abc import Callable
from typing import TYPE_CHECKING

from posecast.errors import (
    InternalError,
    KickedError,
    MalformedError,
    NotFoundError,
    ProtocolError,
    RateLimitedError,
    ReplacedError,
    RoomFullError,
    ServerShutdownError,
    SlowConsumerError,
    TimedOutError,
    TokenExpiredError,
    UnauthenticatedError,
)
from posecast.online.auth.tokens import ReplayGuard, Verifier
from posecast.online.cluster.bus import Bus
from posecast.online.config import ServerConfig
from posecast.online.core.clock import DRIFT_CAP_PPM
from posecast.online.core.connections import Conn, Connections
from posecast.online.core.outbox import Outbox
from posecast.online.core.posestream import PoseStream
from posecast.online.core.ratelimit import FatalBudget, TokenBucket
from posecast.online.core.remote import RemoteRooms
from posecast.online.core.rooms import Rooms
from posecast.online.core.routing import Router
from posecast.online.core.session import (
    Action,
    CalibrateIn,
    ForecastIn,
    FrameIn,
    Join,
    KickIn,
    Leave,
    Phase,
    PoseRateIn,
    Reply,
    ResyncIn,
    SelectorIn,
    Session,
)
from posecast.online.core.tick import EngineInbox, EngineOp, EngineOpKind
from posecast.online.protocol.codec import decode, encode
from posecast.online.protocol.messages import (
    PROTOCOL_V2,
    PROTOCOL_VERSION,
    Bye,
    Error,
    Message,
    Presence,
    Welcome,
)

if TYPE_CHECKING:
    from posecast.online.metrics import Metrics

log = logging.getLogger("posecast.core")
_DROP_REASON = {"OUT_OF_ORDER": "out_of_order", "DUPLICATE": "duplicate", "RATE_LIMITED": "rate"}
# Fatal errors a conforming client can meet (the server's decision, the room's state,
# a slow network or an idle headset): they never spend the address's fatal budget.
LATE_S = 0.05  # check_timeouts this much later than a tick: the server was late

_NOT_THE_CLIENTS_FAULT = frozenset(
    c.code
    for c in (
        ReplacedError, KickedError, ServerShutdownError, RoomFullError, SlowConsumerError,
        TimedOutError,
    )
)  # fmt: skip


class Admission:
    def __init__(
        self,
        cfg: ServerConfig,
        metrics: Metrics,
        conns: Connections,
        rooms: Rooms,
        remote: RemoteRooms,
        router: Router,
        inbox: EngineInbox,
        replay: ReplayGuard,
        verifier: Verifier,
        bus: Bus,
        *,
        wall_offset_s: float,
        changed: Callable[[], None],
    ) -> None:
        """``changed()`` runs after the rooms changed (gauges, what the bus watches)."""
        self.cfg = cfg
        self.metrics = metrics
        self.limits = cfg.limits()
        self.conns = conns
        self.rooms = rooms
        self.remote = remote
        self.router = router
        self.inbox = inbox
        self.replay = replay
        self.verifier = verifier
        self.bus = bus
        self.wall_offset_s = wall_offset_s
        self._changed = changed
        self.fatal = FatalBudget(cfg.fatal_per_ip_per_min)
        self._bug_logs = TokenBucket(1.0, 10.0)  # tracebacks logged: 10, then one a second
        self.shutting_down = False
        self._checked_at: float | None = None  # the last check_timeouts
        self._superseded = metrics.frames_dropped.labels("superseded")  # hot path: bind once

    # --- connections ------------------------------------------------------------------

    def admits(self, ip: str, now: float) -> bool:
        """Whether a new connection from ``ip`` may start its handshake."""
        return not self.fatal.exhausted(ip, now)

    def connect(self, ip: str, now: float, version: int = PROTOCOL_VERSION) -> int:
        """A new connection speaking protocol ``version`` (the handshake's subprotocol)."""
        conn = self.conns.next_id()
        session = Session(
            conn, ip, self.cfg, opened_at=now, wall_offset_s=self.wall_offset_s,
            version=version, verifier=self.verifier,
        )  # fmt: skip
        budget = TokenBucket(self.cfg.error_rate_hz, self.cfg.error_rate_hz)
        stream = PoseStream() if version >= PROTOCOL_V2 else None
        self.conns.conns[conn] = Conn(session, Outbox(self.cfg.reliable_queue, stream), budget)
        self.metrics.connections.labels("pending").inc()
        return conn

    def receive(self, conn: int, data: bytes | str, now: float) -> None:
        """One WebSocket message from ``conn``; every outcome lands in outboxes."""
        c = self.conns.get(conn)
        if c is None or c.session.phase is Phase.CLOSED:
            return
        self.metrics.bytes_in.inc(len(data))
        if isinstance(data, str):  # the spec closes these with 1003 (unsupported data)
            exc = MalformedError("posecast uses binary WebSocket messages only (msgpack)")
            self.metrics.errors.labels(exc.code).inc()
            self._charge(c, exc, now)
            self.end(c, now, final=Error.from_exception(exc), close_code=1003)
            return
        action: Action | None = None
        try:
            incoming = decode(
                data,
                limits=self.limits,
                max_bytes=self.limits.max_message_bytes,
                version=c.session.version,
            )
            action = c.session.handle(incoming, now)
            if action is not None:
                self._apply(c, action, now)
        except ProtocolError as exc:
            self.refuse(c, exc, now)
        except Exception:  # a bug: the sender hears INTERNAL, nobody else notices
            if self._bug_logs.allow(now):  # one bad input must not flood the log
                log.exception("internal error", extra={"conn": conn, "ip": c.session.ip})
            self.metrics.errors.labels(InternalError.code).inc()
            if isinstance(action, Join) or c.session.phase is Phase.AWAIT_HELLO:
                # A join that failed half-way is not a session to go on with: end it
                # (close 1011) rather than leave it joined outside its room.
                internal = InternalError("the server failed to admit this connection", fatal=True)
                self.end(c, now, final=Error.from_exception(internal))
            elif c.errors.allow(now):
                msg = InternalError("the server failed to handle this message")
                self.router.send(c, Error.from_exception(msg), now)

    def refused_by_transport(self, conn: int, exc: ProtocolError, now: float) -> None:
        """websockets closed ``conn`` for what it sent before the codec saw it: past the
        frame cap (1009, ``TOO_LARGE``), a frame that breaks RFC 6455 or a text message
        that is not UTF-8 (1002, 1007: ``MALFORMED``). Counted, and charged, as ``exc``."""
        c = self.conns.get(conn)
        self.metrics.errors.labels(exc.code).inc()
        if c is not None:
            self._charge(c, exc, now)

    def flooded(self, conn: int, now: float) -> None:
        """The shell held ``conn``'s reads back past its read budget for seconds on end
        (``shell/paced.py``): it is cut off with ``RATE_LIMITED`` (fatal), charged to
        its address, and its socket dropped once the error is out."""
        c = self.conns.get(conn)
        self.metrics.floods_cut_off.inc()
        if c is None or c.session.phase is Phase.CLOSED:
            return
        exc = RateLimitedError(
            "sent past the read budget (twice the protocol's limits) for seconds on end: cut off",
            fatal=True,
        )
        self.refuse(c, exc, now)
        self.conns.abort(conn)

    def disconnect(self, conn: int, now: float) -> None:
        """The socket is gone (after any close): forget the connection."""
        c = self.conns.get(conn)
        if c is None:
            return
        self.end(c, now, final=None)
        del self.conns.conns[conn]
        self.metrics.connections.labels(c.session.role or "pending").dec()

    # --- what sessions ask for --------------------------------------------------------

    def _apply(self, c: Conn, action: Action, now: float) -> None:
        s = c.session
        if isinstance(action, FrameIn):
            superseded = self.inbox.frame(s.player, action.frame)
            if superseded:
                self._superseded.inc(superseded)
            self.metrics.frames_in.inc()
            if action.odd_time is not None:
                self.metrics.frame_times_odd.labels(action.odd_time).inc()
        elif isinstance(action, Join):
            self._join(c, action, now)
        elif isinstance(action, Reply):
            self.router.send(c, action.message, now)
        elif isinstance(action, Leave):
            self.end(c, now, final=Bye(reason="bye"), burn=True)
        elif isinstance(action, CalibrateIn):
            op = EngineOp(EngineOpKind.CALIBRATION, s.player, calibration=action.calibration)
            self.inbox.setting(op)
        elif isinstance(action, SelectorIn):
            self._watched_player(s, action.player)
            self.inbox.setting(
                EngineOp(EngineOpKind.SELECTOR, action.player, selector=action.selector)
            )
        elif isinstance(action, PoseRateIn | ResyncIn | ForecastIn):
            stream = c.outbox.stream
            assert stream is not None  # only v2 sessions decode these
            if isinstance(action, PoseRateIn):
                stream.set_rate(action.rate_hz)
            elif isinstance(action, ForecastIn):
                self._forecast(c, action.ms)
            else:
                stream.request_resync()
        elif isinstance(action, KickIn):
            target = self._watched_player(s, action.player)
            kicked = KickedError(action.reason[: self.limits.max_text_bytes])
            log.info("kick", extra={"player": action.player, "by": s.player})
            self.end(target, now, final=Error.from_exception(kicked), burn=True)

    def _watched_player(self, s: Session, player: str) -> Conn:
        room = self.rooms.room_of(player)
        target = self.conns.of_player(player)
        if room is None or room not in s.rooms or target is None:
            raise NotFoundError(f"no player {player!r} in a room you watch", field="player")
        return target

    def _join(self, c: Conn, join: Join, now: float) -> None:
        claims, room = join.claims, join.rooms[0]
        self.replay.check(claims, now + self.wall_offset_s)
        old = self.conns.of_player(claims.player)
        takeover = (  # the same seat as it was: the room sees nothing
            old is not None
            and claims.role == "player"
            and old.session.role == "player"
            and self.rooms.room_of(claims.player) == room
            and old.session.layout == join.layout
            and old.session.name == join.hello.name
            and self._fast(old.session.rate_hz) == self._fast(join.hello.rate_hz)
        )
        if not takeover:  # ROOM_FULL before anyone is displaced
            if claims.role == "player":
                # A player of this room joining it again (another layout) has its seat.
                again = claims.player if self.rooms.room_of(claims.player) == room else ""
                self.rooms.check_join(room, as_player=True, rejoining=again)
                if (
                    len(self.rooms.members(room)) - bool(again) + self.remote.count(room)
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
            self.end(old, now, final=replaced)
        c.session.joined(join)
        if c.outbox.stream is not None and join.hello.pose_rate_hz is not None:
            c.outbox.stream.set_rate(join.hello.pose_rate_hz)
        self._forecast(c, join.hello.forecast_ms or 0.0)  # a takeover's old one ends here
        self.conns.by_player[claims.player] = c.session.conn
        self.metrics.connections.labels("pending").dec()
        self.metrics.connections.labels(claims.role).inc()
        if claims.role == "player" and not takeover:
            moved = self.remote.get(room, claims.player)
            if moved is not None:  # it was in this room on a node that failed: now here
                self.remote.leave(room, claims.player, moved.node, now)
            self.rooms.add_player(room, claims.player, join.hello.name)
            seed = zlib.crc32(claims.player.encode())
            queue = 1 if self._fast(join.hello.rate_hz) else None
            self.inbox.joined(claims.player, seed, join.layout, queue=queue)
            self.bus.joined(room, claims.player, join.hello.name)
            join_msg = Presence("join", room, claims.player, join.hello.name)
            self.router.to_room(room, join_msg, now, skip=claims.player)
        elif claims.role != "player":
            self.rooms.add_watcher(join.rooms, claims.player)
        self.router.send(c, self._welcome(c.session, room, now), now)
        for extra in join.rooms[1:]:  # a backend learns who is in the rooms it watches
            for m in self.router.members(extra):
                self.router.send(c, Presence("join", extra, m.player, m.name), now)
        self._changed()
        log.info(
            "join",
            extra={"player": claims.player, "role": claims.role, "room": room,
                   "takeover": takeover, "ip": c.session.ip},
        )  # fmt: skip

    def _fast(self, rate_hz: float | None) -> bool:
        """A player sending faster than the tick keeps only its newest frame (core/tick.py)."""
        return (rate_hz or 60.0) > self.cfg.tick_hz

    def _forecast(self, c: Conn, ms: float) -> None:
        """``c`` (v2) gets poses forecast ``ms`` ahead, in whole ticks, from the next
        tick on: the router asks the engine thread for that horizon of its rooms."""
        stream = c.outbox.stream
        if stream is not None:  # v1 has no forecast
            stream.set_forecast(ms, self.cfg.tick_hz)
        ahead = 0 if stream is None else stream.ahead
        self.router.listen_ahead(c.session.player, c.session.rooms, ahead)

    def _welcome(self, s: Session, room: str, now: float) -> Welcome:
        return Welcome(  # the router adds the v2 fields for a v2 client
            version=s.version,
            player=s.player,
            session=secrets.token_hex(8),
            role=s.role,
            room=s.rooms[0],
            t=now,
            rate_hz=self.cfg.tick_hz,
            lookahead_frames=self.cfg.delay_frames,  # what the poses lag, not tau itself
            members=self.router.members(room)[: self.limits.max_players],  # a race can overfill
            limits=self.limits,
        )

    # --- endings and errors -----------------------------------------------------------

    def refuse(self, c: Conn, exc: ProtocolError, now: float) -> None:
        self.metrics.errors.labels(exc.code).inc()
        if isinstance(exc, UnauthenticatedError | TokenExpiredError):
            self.metrics.token_refusals.labels(exc.reason).inc()
        if exc.code in _DROP_REASON and not exc.fatal:  # a fatal one drops no frame:
            # the connection ends (RATE_LIMITED for a flood, ``flooded``)
            self.metrics.frames_dropped.labels(_DROP_REASON[exc.code]).inc()
        err = Error.from_exception(exc)
        if len(err.message.encode()) > self.limits.max_text_bytes:
            err = Error(err.code, err.message[: self.limits.max_text_bytes // 4], err.fatal,
                        err.field, err.ref_seq)  # fmt: skip
        if exc.fatal:
            log.info("refused", extra={"code": exc.code, "ip": c.session.ip, "detail": exc.message})
            self._charge(c, exc, now)
            self.end(c, now, final=err)
        elif c.errors.allow(now):
            self.router.send(c, err, now)

    def _charge(self, c: Conn, exc: ProtocolError, now: float) -> None:
        if exc.code not in _NOT_THE_CLIENTS_FAULT and c.session.phase is not Phase.CLOSED:
            self.fatal.charge(c.session.ip, now)

    def end(
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
            code, reason = close_code_of(final)
            self.conns.final(c, encode(final), now, close_code or code, reason)
        if not was_joined:
            return
        if burn and s.claims is not None:
            self.replay.end(s.claims, now + self.wall_offset_s)
            self.bus.burned(s.claims.jti, s.claims.exp)
        drift = s.clock.drift_ppm
        if drift is not None:
            self.metrics.clock_drift.observe(min(abs(drift), DRIFT_CAP_PPM))
        log.info(
            "leave",
            extra={"player": s.player, "role": s.role, "frames": s.frames,
                   "offset_s": s.clock.offset_s, "drift_ppm": drift, "replaced": c.replaced},
        )  # fmt: skip
        if c.replaced or self.conns.by_player.get(s.player) != s.conn:
            return
        del self.conns.by_player[s.player]
        self.router.listen_ahead(s.player, s.rooms, 0)
        played = self.rooms.remove(s.player)
        if played is not None:
            self.inbox.left(s.player)
            self.bus.left(played, s.player)
            if not self.shutting_down:
                self.router.to_room(played, Presence("leave", played, s.player, s.name), now)
        self._changed()

    def check_timeouts(self, now: float) -> None:
        """Hello and idle timeouts, and slow consumers; call about once a tick.

        A client is judged by what it did, not by the server's stalls: when this
        call comes :data:`LATE_S` later than a tick after the last one (the event
        loop or the engine was held up), the clocks of every timeout stop for the
        excess (:meth:`Outbox.pause`, :meth:`Session.paused`)."""
        if self._checked_at is not None:
            late = now - self._checked_at - 1.0 / self.cfg.tick_hz
            if late > LATE_S:
                self.metrics.server_late.inc(late)
                for c in self.conns.conns.values():
                    c.outbox.pause(late)
                    c.session.paused(late)
        self._checked_at = now
        for c in list(self.conns.conns.values()):
            s, box = c.session, c.outbox
            if box.overflowed or box.stalled_for(now) > self.cfg.slow_consumer_s:
                if s.phase is not Phase.CLOSED:
                    self.refuse(c, SlowConsumerError("the client is not reading"), now)
                self.conns.abort(s.conn)
            elif s.phase is Phase.AWAIT_HELLO and now - s.opened_at > self.cfg.hello_timeout_s:
                self.refuse(c, TimedOutError("no hello in time"), now)
            elif (
                s.phase is Phase.JOINED
                and s.role == "player"  # watchers may stay silent: WebSocket pings keep them
                and now - s.last_message_at > self.cfg.idle_timeout_s
            ):
                self.refuse(c, TimedOutError("no message in time"), now)

    def shutdown(self, now: float) -> None:
        """Say ``bye`` to everyone (and nothing else); the writers flush and close."""
        self.shutting_down = True
        for c in list(self.conns.conns.values()):
            self.end(c, now, final=Bye(reason=ServerShutdownError.code))


def close_code_of(final: Message) -> tuple[int, str]:
    """Close code and reason after ``final`` (``proto/README.md``, Transport): 1000
    after ``bye``, 1001 for a shutdown, 1011 for INTERNAL, 1008 for other errors."""
    shutdown, internal = ServerShutdownError.code, InternalError.code
    if isinstance(final, Bye):
        return (1001 if final.reason == shutdown else 1000), final.reason or ""
    if isinstance(final, Error):
        return {shutdown: 1001, internal: 1011}.get(final.code, 1008), final.code
    return 1000, ""
