"""Wire protocols v1 and v2 as typed values: constants, limits, one dataclass per message.

The spec is ``proto/README.md``; :mod:`posecast_client.codec` turns these values into
canonical msgpack bytes and back. Units: metres, seconds, hertz. World frame:
right-handed, +Y up, a character faces +Z. Quaternions are xyzw (scalar last).

Arrays are numpy ``float64``: tracker ``positions (4, 3)`` and ``orientations
(4, 4)`` in :class:`~posecast_client.skeleton.TrackerSlot` order; pose
``positions (19, 3)`` and ``rotations (19, 4)`` in :class:`~posecast_client.skeleton.Joint`
order. Messages that hold arrays compare by identity; compare their wire maps
(:func:`posecast_client.codec.to_wire`) instead.
"""

from __future__ import annotations

from dataclasses import dataclass, fields
from enum import StrEnum
from typing import ClassVar

import numpy as np
from numpy.typing import NDArray

from posecast_client.errors import ProtocolError

F64 = NDArray[np.float64]

PROTOCOL_VERSION = 1
SUBPROTOCOL = "posecast.v1"
PROTOCOL_V2 = 2
SUBPROTOCOL_V2 = "posecast.v2"
SUBPROTOCOLS = {1: SUBPROTOCOL, 2: SUBPROTOCOL_V2}  # this SDK offers v2 first, then v1
POSE_RATES_HZ = (60.0, 30.0, 20.0, 15.0)  # v2 pose rates (divisors of the 60 Hz tick)


class Layout(StrEnum):
    """The tracked points a player sends (``hello.layout``); each picks the server's
    model. The same names as the server's ``posecast.tracking.layouts.Layout``."""

    HMD3_WAIST = "hmd3+waist"  # head, both hands, waist (the default)
    HMD3 = "hmd3"  # headset and controllers only: the frames' waist slot is ignored


LAYOUTS = tuple(Layout)  # the wire enum, in the schema's order
ROLES = ("player", "spectator", "backend")
PRESENCE_EVENTS = ("join", "leave", "stale", "active")
SELECTOR_KINDS = ("anomaly", "target", "obstacle")

MAX_COORD_M = 1000.0  # |x|, |y|, |z| of any position on the wire
QUAT_TOLERANCE = 1e-3  # | |q| - 1 | beyond this is NOT_NORMALISED
MAX_TIME_S = 1e12  # times are seconds in [0, MAX_TIME_S]
MIN_HEIGHT_M, MAX_HEIGHT_M = 0.9, 2.5  # calibrate.height_m
MAX_ID_BYTES = 64  # player and session ids
UINT32_MAX = 2**32 - 1
ALL_VALID = 0b1111  # frame.valid with all four trackers tracked
ALL_SITES_VALID = (1 << 10) - 1  # the largest frame.valid of a tracker set's sites
MAX_LAYOUT_BYTES = 128  # hello.layout: the longest tracker set's name is 124 bytes
POS_UNIT_M = 0.001  # one int16 step of pose.pos_mm
ROT_SCALE = 32767.0  # one int16 step of pose.rot is 1 / ROT_SCALE

# Structural bounds of every v1 message (not configurable).
MAX_DEPTH = 8  # maps and arrays, the root map is depth 1; deeper is MALFORMED
MAX_ARRAY_LEN, MAX_MAP_LEN, MAX_STR_BYTES, MAX_BIN_BYTES = 64, 32, 4096, 256  # TOO_LARGE
# v2: a server message (and so a bin in it) may be up to 16384 bytes.
MAX_SERVER_MESSAGE_BYTES_V2 = 16384

# Which messages each role may send (the server answers FORBIDDEN to the rest).
ROLE_MAY_SEND: dict[str, frozenset[str]] = {
    "player": frozenset({"hello", "calibrate", "frame", "ping", "bye"}),
    "spectator": frozenset({"hello", "ping", "bye"}),
    "backend": frozenset({"hello", "selector", "kick", "ping", "bye"}),
}
ROLE_MAY_SEND_V2 = {r: t | {"pose_rate", "resync", "forecast"} for r, t in ROLE_MAY_SEND.items()}
MAX_FORECAST_MS = 100.0  # v2: the furthest ahead a client may ask its poses to be

# (floor, v1 maximum) of each limit, in canonical order; the defaults are the maxima.
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
    """The limits in force (``welcome.limits``). Defaults: the v1 maxima, which a
    client assumes until its ``welcome`` arrives. Servers may only lower them."""

    max_message_bytes: int = 8192  # bytes of one WebSocket message
    max_rate_hz: int = 120  # frames per second one player may send
    max_players: int = 32  # players in one room
    max_name_bytes: int = 64  # UTF-8 bytes of a display name
    max_room_bytes: int = 64  # UTF-8 bytes of a room name
    max_token_bytes: int = 4096  # UTF-8 bytes of hello.token
    max_text_bytes: int = 512  # UTF-8 bytes of free text (error.message, reasons)
    max_watch_rooms: int = 16  # extra rooms one backend may watch

    def __post_init__(self) -> None:
        for f in fields(self):
            lo, hi = LIMIT_RANGES[f.name]
            if not lo <= getattr(self, f.name) <= hi:
                raise ValueError(f"limit {f.name} outside [{lo}, {hi}]")


DEFAULT_LIMITS = Limits()


def seq_next(seq: int) -> int:
    """The ``seq`` after ``seq``: uint32, wrapping from 2**32 - 1 to 0."""
    return (seq + 1) & UINT32_MAX


def seq_delta(new: int, old: int) -> int:
    """``new - old`` in serial-number arithmetic (RFC 1982), in ``[-2**31, 2**31)``.

    Positive: ``new`` is newer. Zero: a duplicate. Negative: out of order.
    """
    d = (new - old) & UINT32_MAX
    return d - 2**32 if d >= 2**31 else d


@dataclass(frozen=True, slots=True)
class Hello:
    """Client -> server, first message. ``watch``: further rooms (backends only)."""

    TYPE: ClassVar[str] = "hello"
    token: str
    room: str
    name: str
    layout: str | None = None  # absent: hmd3+waist
    rate_hz: float | None = None  # frames per second the client will send; absent: 60
    watch: tuple[str, ...] = ()
    version: int = PROTOCOL_VERSION
    pose_rate_hz: float | None = None  # v2: poses per second to receive (absent: 60)
    forecast_ms: float | None = None  # v2: poses predicted this far ahead, 0-100 (absent: 0)


@dataclass(frozen=True, slots=True)
class Member:
    """A player in the room; v2 adds its ``avatar_id`` (``handle`` on the wire: how pose
    records name it) and its
    ``skeleton`` (108 bytes: 18 x 3 int16 LE bone offsets in 0.1 mm)."""

    player: str
    name: str
    avatar_id: int | None = None
    skeleton: bytes | None = None


@dataclass(frozen=True, slots=True)
class Welcome:
    """Server -> client: the answer to a good ``hello``."""

    TYPE: ClassVar[str] = "welcome"
    version: int
    player: str  # this connection's player id
    session: str  # opaque connection id, for logs and support
    role: str
    room: str
    t: float  # server time at send, seconds
    rate_hz: float  # the room's pose rate
    lookahead_frames: int  # a pose lags its source frame by this many frames
    members: tuple[Member, ...]
    limits: Limits
    pose_rate_hz: float | None = None  # v2: the poses per second this client gets
    forecast_ms: float | None = None  # v2: how far ahead its poses are (whole ticks)


@dataclass(frozen=True, slots=True, eq=False)
class Calibrate:
    """Player -> server: by standing height, or by a T-pose frame (all four trackers,
    or every site of the player's tracker set)."""

    TYPE: ClassVar[str] = "calibrate"
    height_m: float | None = None
    positions: F64 | None = None  # (4, 3) metres: the T-pose frame (sites: (n, 3))
    orientations: F64 | None = None  # (4, 4) xyzw (sites: (n, 4))
    sites: bool = False  # the T-pose is a tracker set's (``sites`` on the wire)

    @property
    def tpose(self) -> bool:
        return self.positions is not None


@dataclass(frozen=True, slots=True, eq=False)
class Frame:
    """Player -> server: one tracker sample. Untracked slots read as origin + identity."""

    TYPE: ClassVar[str] = "frame"
    seq: int
    t: float  # client time the trackers were sampled, seconds
    positions: F64  # (4, 3) metres, TrackerSlot order (sites: (n, 3) in set order,
    # metres, or m/s^2 for an inertial site)
    orientations: F64  # (4, 4) xyzw, unit length (sites: (n, 4))
    valid: int = ALL_VALID  # bit i set: slot (site row) i is tracked
    sites: bool = False  # a tracker set's frame (``sites`` on the wire, not ``trackers``)


@dataclass(frozen=True, slots=True, eq=False)
class Pose:
    """Server -> client: one player's reconstructed avatar (quantised on the wire)."""

    TYPE: ClassVar[str] = "pose"
    player: str
    seq: int  # seq of the source frame (lags it by lookahead_frames)
    t: float  # server time of the tick that made it, seconds
    positions: F64  # (19, 3) world metres, Joint order (v2: rebuilt by FK)
    rotations: F64 | None = None  # (19, 4) world xyzw (v1: not renormalised)
    local_rotations: F64 | None = None  # v2: (19, 4) PELVIS world, then each joint's local
    keyframe: bool = False  # v2: this record was a keyframe
    reach_limited: bool = False  # v2: the head, a hand or a tracked foot or knee missed its tracker


@dataclass(frozen=True, slots=True)
class Presence:
    """Server -> client: ``join``, ``leave``, ``stale`` or ``active``; a v2 ``join``
    carries the player's ``avatar_id`` and ``skeleton``."""

    TYPE: ClassVar[str] = "presence"
    event: str
    room: str
    player: str
    name: str
    avatar_id: int | None = None
    skeleton: bytes | None = None


@dataclass(frozen=True, slots=True)
class Poses:
    """v2 server -> client: one tick's poses as records (see ``records``)."""

    TYPE: ClassVar[str] = "poses"
    t: float
    data: bytes


@dataclass(frozen=True, slots=True)
class Skeleton:
    """v2 server -> client: a player's bone offsets changed (a calibration)."""

    TYPE: ClassVar[str] = "skeleton"
    player: str
    avatar_id: int
    skeleton: bytes


@dataclass(frozen=True, slots=True)
class PoseRate:
    """v2 client -> server: receive ``rate_hz`` (60, 30, 20 or 15) poses a second."""

    TYPE: ClassVar[str] = "pose_rate"
    rate_hz: float


@dataclass(frozen=True, slots=True)
class Forecast:
    """v2 client -> server: receive poses predicted ``ms`` (0-100) milliseconds ahead;
    0 turns it off. Each pose's ``t`` then stands that far past its tick."""

    TYPE: ClassVar[str] = "forecast"
    ms: float


@dataclass(frozen=True, slots=True)
class Resync:
    """v2 client -> server: send keyframes of every avatar with the next poses."""

    TYPE: ClassVar[str] = "resync"


@dataclass(frozen=True, slots=True)
class Selector:
    """Backend -> server: how a player's samples are selected (``anomaly``: ``factor``;
    ``target``: ``joint``, ``point``, ``margin_m``; ``obstacle``: ``joint``, ``point``,
    ``radius_m``)."""

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
    TYPE: ClassVar[str] = "pong"
    t0: float  # the ping's t0, echoed
    t1: float  # server time the ping arrived
    t2: float  # server time the pong left


@dataclass(frozen=True, slots=True)
class Error:
    """Server -> client: a refused message (``fatal``: and the end of the connection)."""

    TYPE: ClassVar[str] = "error"
    code: str
    message: str
    fatal: bool
    field: str | None = None
    ref_seq: int | None = None

    def exception(self) -> ProtocolError:
        """The typed exception of this error (:class:`ProtocolError` for unknown codes)."""
        return ProtocolError.from_wire(
            self.code, self.message, fatal=self.fatal, field=self.field, ref_seq=self.ref_seq
        )


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
