"""The wire messages (v1 and v2) as typed values, with the protocol's constants and limits.

One frozen dataclass per message ``type``; its fields, in declaration order, are the
wire fields in canonical key order (``proto/README.md`` is the spec, and
:mod:`posecast.online.protocol.codec` turns these into bytes and back). Units everywhere:
metres, seconds, a right-handed world with +Y up, quaternions xyzw.

Arrays are numpy ``float64``: tracker positions ``(4, 3)`` and orientations
``(4, 4)`` in :class:`~posecast.tracking.features.TrackerSlot` order; pose positions
``(19, 3)`` and rotations ``(19, 4)`` in :class:`~posecast.skeleton.Joint` order.
Messages holding arrays compare by identity (``eq=False``); compare their wire maps.
"""

from __future__ import annotations

from dataclasses import dataclass, fields
from typing import ClassVar

import numpy as np
from numpy.typing import NDArray

from posecast.errors import ConfigError, ProtocolError
from posecast.tracking.layouts import PlayerLayout

F64 = NDArray[np.float64]

__all__ = [  # the public names, which the package re-exports (posecast.online.protocol)
    "DEFAULT_LIMITS",
    "MESSAGE_TYPES",
    "PROTOCOL_V2",
    "PROTOCOL_VERSION",
    "ROLE_MAY_SEND",
    "ROLE_MAY_SEND_V2",
    "SERVER_SENDS",
    "SERVER_SENDS_V2",
    "SUBPROTOCOL",
    "SUBPROTOCOLS",
    "SUBPROTOCOL_V2",
    "Bye",
    "Calibrate",
    "Error",
    "Forecast",
    "Frame",
    "Hello",
    "Kick",
    "Limits",
    "Member",
    "Message",
    "Ping",
    "Pong",
    "Pose",
    "PoseRate",
    "Poses",
    "Presence",
    "Resync",
    "Selector",
    "Skeleton",
    "Welcome",
    "seq_delta",
    "seq_next",
]

PROTOCOL_VERSION = 1
SUBPROTOCOL = "posecast.v1"
PROTOCOL_V2 = 2
SUBPROTOCOL_V2 = "posecast.v2"
VERSIONS = (1, 2)  # the versions this peer speaks
SUBPROTOCOLS = {1: SUBPROTOCOL, 2: SUBPROTOCOL_V2}
POSE_RATES_HZ = (60.0, 30.0, 20.0, 15.0)  # v2 per-client pose rates: divisors of the tick
MAX_FORECAST_MS = 100.0  # v2: the furthest ahead a client may ask its poses to be

ROLES = ("player", "spectator", "backend")
PRESENCE_EVENTS = ("join", "leave", "stale", "active")
SELECTOR_KINDS = ("anomaly", "target", "obstacle")

MAX_COORD_M = 1000.0  # |x|, |y|, |z| of any position on the wire
QUAT_TOLERANCE = 1e-3  # | |q| - 1 | above this is NOT_NORMALISED; below, q is renormalised
MIN_HEIGHT_M, MAX_HEIGHT_M = 0.9, 2.5  # calibrate.height_m (the engine's accepted range)
ALL_TRACKERS_VALID = 0b1111
UINT32_MAX = 2**32 - 1
MAX_TIME_S = 1e12  # client and server times are seconds in [0, MAX_TIME_S]
MAX_ID_BYTES = 64  # player and session ids (server-made)
MAX_LAYOUT_BYTES = 128  # a hello's layout: the longest tracker set's name is 124
MAX_LOOKAHEAD_FRAMES = 255

# Structural bounds on any v1 message (not configurable): exceeding a size one is
# TOO_LARGE, nesting deeper (counting maps and arrays, the root map is 1) is MALFORMED.
MAX_DEPTH = 8
MAX_ARRAY_LEN = 64
MAX_MAP_LEN = 32
MAX_STR_BYTES = 4096
MAX_BIN_BYTES = 256
# v2: a server message may be up to 16384 bytes (a welcome with 32 skeletons, a poses
# message with 31 keyframes), so bins may be that long too (only poses.data is).
MAX_SERVER_MESSAGE_BYTES_V2 = 16384
MAX_BIN_BYTES_V2 = MAX_SERVER_MESSAGE_BYTES_V2

# Which message types each role may send; the server answers FORBIDDEN to the rest.
ROLE_MAY_SEND: dict[str, frozenset[str]] = {
    "player": frozenset({"hello", "calibrate", "frame", "ping", "bye"}),
    "spectator": frozenset({"hello", "ping", "bye"}),
    "backend": frozenset({"hello", "selector", "kick", "ping", "bye"}),
}
SERVER_SENDS = frozenset({"welcome", "pose", "presence", "pong", "error", "bye"})
# v2: every role may also ask for a pose rate, a forecast and keyframes; the server sends
# poses (one message per tick) and skeletons instead of pose.
ROLE_MAY_SEND_V2: dict[str, frozenset[str]] = {
    role: types | {"pose_rate", "resync", "forecast"} for role, types in ROLE_MAY_SEND.items()
}
SERVER_SENDS_V2 = (SERVER_SENDS - {"pose"}) | {"poses", "skeleton"}

# (floor, v1 maximum) of each limit; the defaults are the maxima.
LIMIT_RANGES: dict[str, tuple[int, int]] = {
    "max_message_bytes": (1024, 8192),
    "max_rate_hz": (1, 120),
    "max_players": (1, 32),
    "max_name_bytes": (1, 64),
    "max_room_bytes": (1, 64),
    "max_token_bytes": (0, 4096),
    "max_text_bytes": (64, 512),
    "max_watch_rooms": (0, 16),
}


@dataclass(frozen=True, slots=True)
class Limits:
    """Protocol limits. The defaults are the v1 maxima; server config may lower them.

    Attributes:
        max_message_bytes: bytes of one WebSocket message (8192).
        max_rate_hz: frames per second a player may send (120).
        max_players: players in one room (32).
        max_name_bytes: UTF-8 bytes of a display name (64).
        max_room_bytes: UTF-8 bytes of a room name (64).
        max_token_bytes: UTF-8 bytes of ``hello.token`` (4096).
        max_text_bytes: UTF-8 bytes of free text: error messages, reasons (512).
        max_watch_rooms: extra rooms one backend may watch (16).
    """

    max_message_bytes: int = 8192
    max_rate_hz: int = 120
    max_players: int = 32
    max_name_bytes: int = 64
    max_room_bytes: int = 64
    max_token_bytes: int = 4096
    max_text_bytes: int = 512
    max_watch_rooms: int = 16

    def __post_init__(self) -> None:
        for f in fields(self):
            lo, hi = LIMIT_RANGES[f.name]
            value = getattr(self, f.name)
            if type(value) is not int or not lo <= value <= hi:
                raise ConfigError(f"limit {f.name}={value!r} outside [{lo}, {hi}]")


DEFAULT_LIMITS = Limits()


def seq_next(seq: int) -> int:
    """The ``seq`` after ``seq`` (uint32, wraps from 2**32 - 1 to 0)."""
    return (seq + 1) & UINT32_MAX


def seq_delta(new: int, old: int) -> int:
    """``new - old`` in serial-number arithmetic (RFC 1982), in ``[-2**31, 2**31)``.

    Positive: ``new`` is newer. Zero: a duplicate. Negative: out of order.
    """
    d = (new - old) & UINT32_MAX
    return d - 2**32 if d >= 2**31 else d


@dataclass(frozen=True, slots=True)
class Hello:
    """Client -> server, first message, every role. ``watch``: backends only."""

    TYPE: ClassVar[str] = "hello"
    version: int
    token: str
    room: str
    name: str
    # A named layout or a tracker set; absent: the server takes Layout.HMD3_WAIST
    layout: PlayerLayout | None = None
    rate_hz: float | None = None  # frames per second the client will send; absent: 60
    watch: tuple[str, ...] = ()  # further rooms a backend watches
    pose_rate_hz: float | None = None  # v2: poses per second to receive; absent: 60
    forecast_ms: float | None = None  # v2: poses predicted this far ahead; absent: 0


@dataclass(frozen=True, slots=True)
class Member:
    """A player in a room. v2 adds its ``avatar_id`` (``handle`` on the wire: how
    ``poses`` records name it on this connection) and its ``skeleton``: 108 bytes, the
    bone offsets ``SPINE`` .. ``RIGHT_TOE`` from their parents at the player's calibrated
    scale, 18 x 3 int16 LE in 0.1 mm (:mod:`posecast.online.protocol.records`)."""

    player: str
    name: str
    avatar_id: int | None = None
    skeleton: bytes | None = None


@dataclass(frozen=True, slots=True)
class Welcome:
    """Server -> client, the answer to a good ``hello``."""

    TYPE: ClassVar[str] = "welcome"
    version: int
    player: str  # this connection's id (spectators and backends get one too)
    session: str
    role: str
    room: str
    t: float  # server time, seconds
    rate_hz: float  # pose rate of the room
    lookahead_frames: int  # poses lag their source frames by this many frames
    members: tuple[Member, ...]
    limits: Limits
    pose_rate_hz: float | None = None  # v2: the poses per second this client gets
    forecast_ms: float | None = None  # v2: how far ahead its poses are (whole ticks)


@dataclass(frozen=True, slots=True, eq=False)
class Calibrate:
    """Player -> server: by standing height, or by a T-pose (``pos``/``quat`` set)."""

    TYPE: ClassVar[str] = "calibrate"
    height_m: float | None = None
    pos: F64 | None = None  # (4, 3) the T-pose frame, metres (sites: (n, 3), set order)
    quat: F64 | None = None  # (4, 4) xyzw
    sites: bool = False  # the T-pose came as a tracker set's ``sites``, not ``trackers``

    @property
    def tpose(self) -> bool:
        return self.pos is not None


@dataclass(frozen=True, slots=True, eq=False)
class Frame:
    """Player -> server: one tracker frame. Invalid slots read as origin + identity."""

    TYPE: ClassVar[str] = "frame"
    seq: int
    t: float  # client time, seconds
    pos: F64  # (4, 3) metres, TrackerSlot order (sites: (n, 3) in set order, m or m/s^2)
    quat: F64  # (4, 4) xyzw, unit length
    valid: int = ALL_TRACKERS_VALID  # bit i set: slot i is tracked
    sites: bool = False  # a tracker set's frame (``sites`` on the wire, not ``trackers``)


@dataclass(frozen=True, slots=True, eq=False)
class Pose:
    """Server -> client: one reconstructed avatar (quantised on the wire)."""

    TYPE: ClassVar[str] = "pose"
    player: str
    seq: int  # seq of the source frame
    t: float  # server time, seconds
    positions: F64  # (19, 3) world metres, Joint order
    rotations: F64 | None = None  # (19, 4) world xyzw


@dataclass(frozen=True, slots=True)
class Presence:
    TYPE: ClassVar[str] = "presence"
    event: str  # join | leave | stale | active
    room: str
    player: str
    name: str
    avatar_id: int | None = None  # v2 join: the new player's avatar id
    skeleton: bytes | None = None  # v2 join: its skeleton (see Member)

    def v1(self) -> Presence:
        """The same presence without the v2 fields."""
        return Presence(self.event, self.room, self.player, self.name)


@dataclass(frozen=True, slots=True)
class Poses:
    """v2 server -> client: every pose of one tick for this client, as records
    (:mod:`posecast.online.protocol.records`); ``t`` is the newest tick's time."""

    TYPE: ClassVar[str] = "poses"
    t: float
    data: bytes


@dataclass(frozen=True, slots=True)
class Skeleton:
    """v2 server -> client: a player's calibration changed; FK from now on with this."""

    TYPE: ClassVar[str] = "skeleton"
    player: str
    avatar_id: int
    skeleton: bytes  # 108 bytes, as Member.skeleton


@dataclass(frozen=True, slots=True)
class PoseRate:
    """v2 client -> server: receive ``rate_hz`` poses per second (60, 30, 20 or 15)."""

    TYPE: ClassVar[str] = "pose_rate"
    rate_hz: float


@dataclass(frozen=True, slots=True)
class Forecast:
    """v2 client -> server: receive poses predicted ``ms`` milliseconds ahead (0 to
    100; 0 turns the forecast off)."""

    TYPE: ClassVar[str] = "forecast"
    ms: float


@dataclass(frozen=True, slots=True)
class Resync:
    """v2 client -> server: send a keyframe of every avatar with its next pose."""

    TYPE: ClassVar[str] = "resync"


@dataclass(frozen=True, slots=True)
class Selector:
    """Backend -> server: choose how a player's samples are selected.

    ``anomaly``: ``factor``; ``target``: ``joint``, ``point``, ``margin_m``;
    ``obstacle``: ``joint``, ``point``, ``radius_m``. Absent optionals take the
    engine's defaults.
    """

    TYPE: ClassVar[str] = "selector"
    player: str
    kind: str
    joint: str | None = None
    point: tuple[float, float, float] | None = None  # world metres
    radius_m: float | None = None
    margin_m: float | None = None
    factor: float | None = None


@dataclass(frozen=True, slots=True)
class Kick:
    TYPE: ClassVar[str] = "kick"
    player: str
    reason: str | None = None


@dataclass(frozen=True, slots=True)
class Ping:
    TYPE: ClassVar[str] = "ping"
    t0: float  # client time at send


@dataclass(frozen=True, slots=True)
class Pong:
    """``offset = ((t1 - t0) + (t2 - t3)) / 2``, ``rtt = (t3 - t0) - (t2 - t1)``."""

    TYPE: ClassVar[str] = "pong"
    t0: float  # echoed client time
    t1: float  # server time the ping arrived
    t2: float  # server time the pong left


@dataclass(frozen=True, slots=True)
class Error:
    """Server -> client: a refused message or the end of the connection (``fatal``)."""

    TYPE: ClassVar[str] = "error"
    code: str
    message: str
    fatal: bool
    field: str | None = None
    ref_seq: int | None = None

    @classmethod
    def from_exception(cls, exc: ProtocolError) -> Error:
        return cls(exc.code, exc.message, exc.fatal, exc.field, exc.ref_seq)

    def to_exception(self) -> ProtocolError:
        """The matching :class:`ProtocolError` (its base class for an unknown code)."""
        exc = ProtocolError.for_code(self.code)(
            self.message, field=self.field, ref_seq=self.ref_seq, fatal=self.fatal
        )
        exc.code = self.code
        return exc


@dataclass(frozen=True, slots=True)
class Bye:
    TYPE: ClassVar[str] = "bye"
    reason: str | None = None


Message = (
    Hello
    | Welcome
    | Calibrate
    | Frame
    | Pose
    | Presence
    | Selector
    | Kick
    | Ping
    | Pong
    | Error
    | Bye
    | Poses
    | Skeleton
    | PoseRate
    | Resync
    | Forecast
)
MESSAGE_TYPES: tuple[type[Message], ...] = (
    Hello,
    Welcome,
    Calibrate,
    Frame,
    Pose,
    Presence,
    Selector,
    Kick,
    Ping,
    Pong,
    Error,
    Bye,
    Poses,
    Skeleton,
    PoseRate,
    Resync,
    Forecast,
)
V1_TYPES = frozenset(t.TYPE for t in MESSAGE_TYPES[:12])
V2_TYPES = (V1_TYPES - {"pose"}) | {"poses", "skeleton", "pose_rate", "resync", "forecast"}
