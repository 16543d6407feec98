"""One connection's protocol state machine (pure): a decoded message in, an action out.

::

    AWAIT_HELLO --hello ok--> JOINED --bye / fatal error / kick--> CLOSED

The session checks what only this connection decides: the token, the role's right
to send each message type, frame order (``seq``, serial-number arithmetic), the
per-connection rate limits and the client's clock. It raises the matching
:class:`~posecast.errors.ProtocolError` for anything it refuses. What involves other
connections (room capacity, replacing a player, routing) is the hub's
(:mod:`posecast.online.core.hub`). No I/O and no clock: the caller passes ``now``, the
server time (the process's monotonic clock, as on the wire); token times are Unix
seconds, ``now + wall_offset_s``.
"""

from __future__ import annotations

import enum
from dataclasses import dataclass, field

import numpy as np

from posecast.errors import (
    AlreadyJoinedError,
    BadFieldError,
    CalibrationFailedError,
    ConfigError,
    DuplicateError,
    ForbiddenError,
    LayoutUnsupportedError,
    NotJoinedError,
    OutOfOrderError,
    RateLimitedError,
)
from posecast.geometry.rotations import quat_identity
from posecast.online.auth.tokens import Claims, Verifier
from posecast.online.config import ServerConfig
from posecast.online.core.clock import ClockEstimator, FrameTimes
from posecast.online.core.ratelimit import TokenBucket
from posecast.online.engine.calibration import Calibration
from posecast.online.engine.selectors import (
    DefaultSelector,
    ObstacleSelector,
    SampleSelector,
    TargetSelector,
)
from posecast.online.engine.types import TrackerFrame
from posecast.online.protocol.messages import (
    PROTOCOL_V2,
    PROTOCOL_VERSION,
    ROLE_MAY_SEND,
    ROLE_MAY_SEND_V2,
    Bye,
    Calibrate,
    Forecast,
    Frame,
    Hello,
    Kick,
    Message,
    Ping,
    Pong,
    PoseRate,
    Resync,
    Selector,
    seq_delta,
)
from posecast.skeleton import Joint
from posecast.tracking.layouts import Layout, PlayerLayout, model_layout
from posecast.tracking.sites import Kind, TrackerSet


class Phase(enum.Enum):
    AWAIT_HELLO = "await_hello"
    JOINED = "joined"
    CLOSED = "closed"


def requested_layout(hello: Hello) -> PlayerLayout:
    """The tracker layout or set a ``hello`` asks for (absent: the 4-point layout)."""
    return hello.layout or Layout.HMD3_WAIST


@dataclass(frozen=True)
class Join:
    claims: Claims
    hello: Hello
    rooms: tuple[str, ...]  # hello.room first, then the rooms a backend watches

    @property
    def layout(self) -> PlayerLayout:
        return requested_layout(self.hello)


@dataclass(frozen=True)
class FrameIn:
    frame: TrackerFrame
    odd_time: str | None = None  # what FrameTimes found odd about frame.t, if anything


@dataclass(frozen=True)
class CalibrateIn:
    calibration: Calibration


@dataclass(frozen=True)
class SelectorIn:
    player: str
    selector: SampleSelector


@dataclass(frozen=True)
class KickIn:
    player: str
    reason: str


@dataclass(frozen=True)
class Reply:
    message: Message


@dataclass(frozen=True)
class Leave:
    reason: str | None


@dataclass(frozen=True)
class PoseRateIn:
    """v2: the client wants ``rate_hz`` poses a second from now on."""

    rate_hz: float


@dataclass(frozen=True)
class ForecastIn:
    """v2: the client wants poses forecast ``ms`` milliseconds ahead from now on."""

    ms: float


@dataclass(frozen=True)
class ResyncIn:
    """v2: the client wants a keyframe of every avatar with its next poses."""


Action = (
    Join | FrameIn | CalibrateIn | SelectorIn | KickIn | Reply | Leave | PoseRateIn | ResyncIn
    | ForecastIn
)  # fmt: skip


@dataclass
class Session:
    """The state of one connection. ``conn`` is the hub's serial number for it."""

    conn: int
    ip: str
    cfg: ServerConfig
    opened_at: float
    wall_offset_s: float = 0.0  # Unix time minus server time, for token iat/exp
    version: int = PROTOCOL_VERSION  # the subprotocol the handshake chose (1 or 2)
    verifier: Verifier | None = None  # the hub's; None: one built from cfg (tests)
    phase: Phase = Phase.AWAIT_HELLO
    claims: Claims | None = None
    name: str = ""
    rate_hz: float | None = None  # the hello's input rate (absent: 60)
    rooms: tuple[str, ...] = ()
    layout: PlayerLayout = Layout.HMD3_WAIST  # the hello's tracker layout or set, once joined
    last_seq: int | None = None
    last_message_at: float = 0.0
    clock: ClockEstimator = field(default_factory=ClockEstimator)
    frame_times: FrameTimes = field(default_factory=FrameTimes)
    frames: int = 0
    _held: tuple[np.ndarray, np.ndarray] | None = None  # last accepted (pos, quat)
    _frame_bucket: TokenBucket | None = None
    _control_bucket: TokenBucket | None = None

    def __post_init__(self) -> None:
        self.last_message_at = self.opened_at
        self._frame_bucket = TokenBucket(self.cfg.max_rate_hz, self.cfg.rate_burst)
        self._control_bucket = TokenBucket(self.cfg.control_rate_hz, self.cfg.control_rate_hz)

    @property
    def player(self) -> str:
        assert self.claims is not None
        return self.claims.player

    @property
    def role(self) -> str:
        return self.claims.role if self.claims is not None else ""

    def handle(self, msg: Message, now: float) -> Action | None:
        """What ``msg`` asks for; raises ProtocolError for a refused message."""
        self.last_message_at = now
        if self.phase is Phase.AWAIT_HELLO:
            if not isinstance(msg, Hello):
                raise NotJoinedError(f"{msg.TYPE} before hello", field="type")
            return self._hello(msg, now)
        if isinstance(msg, Hello):
            raise AlreadyJoinedError("this connection has already joined", field="type")
        may_send = ROLE_MAY_SEND_V2 if self.version >= PROTOCOL_V2 else ROLE_MAY_SEND
        if msg.TYPE not in may_send[self.role]:
            raise ForbiddenError(f"a {self.role} may not send {msg.TYPE}", field="type")
        if isinstance(msg, Frame):
            return self._frame(msg, now)
        assert self._control_bucket is not None
        if not self._control_bucket.allow(now):
            raise RateLimitedError(f"more than {self.cfg.control_rate_hz:g} messages/s")
        if isinstance(msg, Ping):
            self.clock.add(now, msg.t0)
            return Reply(Pong(t0=msg.t0, t1=now, t2=now))
        if isinstance(msg, Bye):
            return Leave(msg.reason)
        if isinstance(msg, Calibrate):
            return CalibrateIn(_calibration(msg, self.layout))
        if isinstance(msg, Selector):
            return SelectorIn(msg.player, _selector(msg))
        if isinstance(msg, Kick):
            return KickIn(msg.player, msg.reason or "kicked by the game backend")
        if isinstance(msg, PoseRate):
            return PoseRateIn(msg.rate_hz)
        if isinstance(msg, Resync):
            return ResyncIn()
        if isinstance(msg, Forecast):
            return ForecastIn(msg.ms)
        raise ForbiddenError(f"{msg.TYPE} is not for a server", field="type")  # pragma: no cover

    def _hello(self, hello: Hello, now: float) -> Join:
        layout = requested_layout(hello)
        if self.verifier is None:
            self.verifier = Verifier(self.cfg.key_set(), self.cfg.token_leeway_s)
        claims = self.verifier.verify(hello.token, now + self.wall_offset_s)
        # After the token: what this server serves and how it is started is for
        # clients it admits, not for anyone who can open a socket.
        model = model_layout(layout)
        if model not in self.cfg.served_layouts:
            what = "tracker sets are" if isinstance(layout, TrackerSet) else f"{layout!r} is"
            served = ",".join(self.cfg.served_layouts)
            raise LayoutUnsupportedError(
                f"layout {what} not served here (layouts {served}): start the server with"
                f" {model} in its layouts, --layouts {served},{model} (POSECAST_LAYOUTS)",
                field="layout",
            )
        if not claims.allows_room(hello.room):
            raise ForbiddenError("the token does not admit this room", field="room", fatal=True)
        if hello.watch and claims.role != "backend":
            raise ForbiddenError("only a backend may watch rooms", field="watch", fatal=True)
        for room in hello.watch:
            if not claims.allows_room(room):
                raise ForbiddenError(
                    f"the token does not admit room {room!r}", field="watch", fatal=True
                )
        rooms = tuple(dict.fromkeys((hello.room, *hello.watch)))
        return Join(claims, hello, rooms)

    def joined(self, join: Join) -> None:
        """The hub admitted ``join``: the session is live."""
        self.phase = Phase.JOINED
        self.claims = join.claims
        self.layout = join.layout
        self.name = join.hello.name
        self.rate_hz = join.hello.rate_hz
        self.rooms = join.rooms

    def paused(self, late_s: float) -> None:
        """The server was ``late_s`` late (its event loop or tick held up): the
        timeouts that judge this client leave that time out."""
        self.opened_at += late_s
        self.last_message_at += late_s

    def _frame(self, msg: Frame, now: float) -> FrameIn:
        assert self._frame_bucket is not None
        # The rate is judged on the frames' own times (FrameTimes): frames that waited
        # in the kernel while the server was busy arrive together and are no burst.
        judged, odd = self.frame_times.judge(msg.t, now)
        if not self._frame_bucket.allow(judged):
            raise RateLimitedError(
                f"more than {self.cfg.max_rate_hz} frames/s", ref_seq=msg.seq, field="seq"
            )
        if self.last_seq is not None:
            d = seq_delta(msg.seq, self.last_seq)
            if d == 0:
                raise DuplicateError(f"seq {msg.seq} again", ref_seq=msg.seq, field="seq")
            if d < 0:
                raise OutOfOrderError(
                    f"seq {msg.seq} after {self.last_seq}", ref_seq=msg.seq, field="seq"
                )
        tracker_set = self.layout if isinstance(self.layout, TrackerSet) else None
        _check_rows(msg.sites, len(msg.pos), tracker_set, msg.seq)  # refused: nothing counts
        self.last_seq = msg.seq
        self.frames += 1
        if odd == "jump":
            self.clock.restart()  # the client's clock was set: no drift across it
        if odd is None or odd == "jump":
            self.clock.add(now, msg.t)
        pos, quat = msg.pos, msg.quat
        if msg.valid != (1 << len(pos)) - 1 and self._held is not None:
            # A lost tracker holds its last pose rather than jumping to the origin (a
            # lost IMU its orientation, with no acceleration).
            pos, quat = pos.copy(), quat.copy()
            for i in range(len(pos)):
                if not msg.valid >> i & 1:
                    pos[i], quat[i] = self._held[0][i], self._held[1][i]
                    if tracker_set is not None and tracker_set.entries[i][1] is Kind.INERTIAL:
                        pos[i] = 0.0
        self._held = (pos, quat)
        if tracker_set is not None:
            pos, quat = tracker_set.to_rows(pos, _ORIGIN), tracker_set.to_rows(quat, _IDENT)
        return FrameIn(TrackerFrame(msg.seq, pos, quat), odd)

    def close(self) -> None:
        self.phase = Phase.CLOSED


_ORIGIN = np.zeros(3)
_IDENT = quat_identity()


def _check_rows(sites: bool, n: int, tracker_set: TrackerSet | None, seq: int | None) -> None:
    """A frame's (or T-pose's) rows must be what the layout sends: 4 ``trackers`` for
    a named layout, one ``sites`` row per site of a tracker set."""
    if tracker_set is None:
        if sites:
            raise BadFieldError(
                "this layout sends trackers, not sites (sites are for a tracker set)",
                field="sites",
                ref_seq=seq,
            )
        return
    if not sites:
        raise BadFieldError(
            f"a tracker set sends sites, not trackers: {len(tracker_set)} rows for "
            f"{tracker_set.name}",
            field="trackers",
            ref_seq=seq,
        )
    if n != len(tracker_set):
        raise BadFieldError(
            f"sites has {n} rows; the set {tracker_set.name} has {len(tracker_set)}",
            field="sites",
            ref_seq=seq,
        )


def _calibration(msg: Calibrate, layout: PlayerLayout) -> Calibration:
    where = "height_m" if msg.height_m is not None else ("sites" if msg.sites else "trackers")
    try:
        if msg.height_m is not None:
            return Calibration.from_height(msg.height_m)
        assert msg.pos is not None and msg.quat is not None
        if isinstance(layout, TrackerSet):
            _check_rows(msg.sites, len(msg.pos), layout, None)
            return Calibration.from_tpose_sites(
                layout.to_rows(msg.pos, _ORIGIN), layout.to_rows(msg.quat, _IDENT), layout.kinds()
            )
        _check_rows(msg.sites, len(msg.pos), None, None)
        return Calibration.from_tpose(msg.pos, msg.quat, waist=layout != Layout.HMD3)
    except ConfigError as exc:
        raise CalibrationFailedError(exc.message, field=where) from None


def _selector(msg: Selector) -> SampleSelector:
    if msg.kind == "anomaly":  # the engine's own, as configured (factor: the message's)
        return DefaultSelector(msg.factor)
    assert msg.joint is not None and msg.point is not None
    joint = Joint[msg.joint]
    if msg.kind == "target":
        margin = 0.02 if msg.margin_m is None else msg.margin_m
        return TargetSelector(joint, msg.point, margin)
    return ObstacleSelector(joint, msg.point, 0.2 if msg.radius_m is None else msg.radius_m)
