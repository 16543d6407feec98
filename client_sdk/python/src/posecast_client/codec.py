"""Bytes <-> messages for protocols v1 and v2. Pure functions: no sockets, no clocks, no state.

This is an implementation of ``proto/README.md`` written apart from the server's;
the shared vectors in ``proto/vectors/`` keep the two honest.

:func:`encode` writes the canonical bytes: a msgpack map with ``type`` first and then
the fields in spec order (:data:`FIELDS`), absent optionals left out, floats as
float64 and everything else in its smallest msgpack form, which is what
``msgpack.packb(..., use_bin_type=True)`` writes for that map.

:func:`decode` accepts any valid encoding and reports the first rule broken, in the
spec's order: size (TOO_LARGE), one msgpack value within the structural bounds
(MALFORMED / TOO_LARGE), a root map, depth and string keys (MALFORMED), ``type``
(BAD_FIELD / UNKNOWN_TYPE), then the fields of that type.

``version`` is the connection's protocol (the subprotocol the server selected): v2
knows ``poses``, ``skeleton``, ``pose_rate``, ``forecast`` and ``resync`` but no
``pose``, wants ``version`` 2 in ``hello``, a ``handle`` (the avatar id,
``avatar_id`` in the message classes) and ``skeleton`` for every ``welcome`` member
and ``presence`` join, and lets a server message and its bins reach 16384 bytes.
``poses.data`` is opaque here: :mod:`posecast_client.records` reads it.
"""

from __future__ import annotations

import math
import re
from collections.abc import Callable
from typing import Any, TypeVar

import msgpack
import numpy as np

from posecast_client.errors import (
    BadFieldError,
    MalformedError,
    NotNormalisedError,
    OutOfRangeError,
    ProtocolError,
    TooLargeError,
    UnknownTypeError,
    VersionUnsupportedError,
)
from posecast_client.protocol import (
    ALL_SITES_VALID,
    ALL_VALID,
    DEFAULT_LIMITS,
    F64,
    LAYOUTS,
    LIMIT_RANGES,
    MAX_ARRAY_LEN,
    MAX_BIN_BYTES,
    MAX_COORD_M,
    MAX_DEPTH,
    MAX_FORECAST_MS,
    MAX_HEIGHT_M,
    MAX_ID_BYTES,
    MAX_LAYOUT_BYTES,
    MAX_MAP_LEN,
    MAX_SERVER_MESSAGE_BYTES_V2,
    MAX_STR_BYTES,
    MAX_TIME_S,
    MIN_HEIGHT_M,
    POS_UNIT_M,
    POSE_RATES_HZ,
    PRESENCE_EVENTS,
    PROTOCOL_V2,
    PROTOCOL_VERSION,
    QUAT_TOLERANCE,
    ROLE_MAY_SEND_V2,
    ROLES,
    ROT_SCALE,
    SELECTOR_KINDS,
    UINT32_MAX,
    Bye,
    Calibrate,
    Error,
    Forecast,
    Frame,
    Hello,
    Kick,
    Limits,
    Member,
    Message,
    Ping,
    Pong,
    Pose,
    PoseRate,
    Poses,
    Presence,
    Resync,
    Selector,
    Skeleton,
    Welcome,
)
from posecast_client.sites import MAX_SITES, tracker_set
from posecast_client.skeleton import JOINT_NAMES, NUM_JOINTS

Map = dict[str, Any]
T = TypeVar("T")

# Canonical key order of every message (after "type"): the spec's field tables.
FIELDS: dict[str, tuple[str, ...]] = {
    "hello": ("version", "token", "room", "name", "layout", "rate_hz", "watch", "pose_rate_hz",
              "forecast_ms"),
    "welcome": ("version", "player", "session", "role", "room", "t", "rate_hz",
                "lookahead_frames", "members", "limits", "pose_rate_hz", "forecast_ms"),
    "calibrate": ("height_m", "tpose", "trackers", "sites"),
    "frame": ("seq", "t", "trackers", "sites", "valid"),
    "pose": ("player", "seq", "t", "root", "pos_mm", "rot"),
    "presence": ("event", "room", "player", "name", "handle", "skeleton"),
    "selector": ("player", "kind", "joint", "point", "radius_m", "margin_m", "factor"),
    "kick": ("player", "reason"),
    "ping": ("t0",),
    "pong": ("t0", "t1", "t2"),
    "error": ("code", "message", "fatal", "field", "ref_seq"),
    "bye": ("reason",),
    "poses": ("t", "data"),
    "skeleton": ("player", "handle", "skeleton"),
    "pose_rate": ("rate_hz",),
    "resync": (),
    "forecast": ("ms",),
}  # fmt: skip
V1_TYPES = frozenset(FIELDS) - {"poses", "skeleton", "pose_rate", "resync", "forecast"}
V2_TYPES = frozenset(FIELDS) - {"pose"}
_V2_CLIENT_TYPES = frozenset().union(*ROLE_MAY_SEND_V2.values())
_SELECTOR_APPLIES = {
    "anomaly": {"factor"},
    "target": {"joint", "point", "margin_m"},
    "obstacle": {"joint", "point", "radius_m"},
}
ID_PATTERN = _ID = re.compile(r"[A-Za-z0-9_.:-]+")  # rooms, player and session ids
_CODE = re.compile(r"[A-Z][A-Z0-9_]{0,31}")
_CONTROL = re.compile(r"[\x00-\x1f\x7f]")
_LEAVES = (type(None), bool, int, float, str, bytes)
_I16 = np.dtype("<i2")
SKELETON_BYTES = 108  # a v2 skeleton: 18 x 3 int16
POS_BYTES, ROT_BYTES = (NUM_JOINTS - 1) * 3 * 2, NUM_JOINTS * 4 * 2  # 108, 152


# --- decoding ------------------------------------------------------------------------


def decode(
    data: bytes,
    *,
    limits: Limits = DEFAULT_LIMITS,
    max_bytes: int | None = None,
    version: int = PROTOCOL_VERSION,
) -> Message:
    """Parse and validate one WebSocket message.

    Args:
        data: one whole binary WebSocket message.
        limits: the limits in force; the defaults are the v1 maxima.
        max_bytes: a tighter size cap than the version's bound, if given.
        version: the connection's protocol, 1 or 2.

    Raises:
        ProtocolError: the subclass of the first rule broken, with ``field`` set where
            the spec names one (and ``ref_seq`` for a frame whose ``seq`` was read).
    """
    v2 = version >= PROTOCOL_V2
    top = MAX_SERVER_MESSAGE_BYTES_V2 if v2 else limits.max_message_bytes
    cap = top if max_bytes is None else min(max_bytes, top)
    if len(data) > cap:
        raise TooLargeError(f"message of {len(data)} bytes, limit {cap}")
    try:
        obj = msgpack.unpackb(
            data,
            raw=False,  # str must be UTF-8
            strict_map_key=True,  # str (or bin, refused below) keys only
            max_str_len=MAX_STR_BYTES,  # the bounds are checked at each header,
            max_bin_len=cap if v2 else MAX_BIN_BYTES,  # before anything is allocated
            max_array_len=MAX_ARRAY_LEN,
            max_map_len=MAX_MAP_LEN,
        )
    except ValueError as exc:  # ExtraData, FormatError, StackError, UnicodeDecodeError...
        if "exceeds max_" in str(exc):
            raise TooLargeError(f"msgpack: {exc}") from None
        raise MalformedError(f"not one msgpack value: {type(exc).__name__}") from None
    if type(obj) is not dict:
        raise MalformedError("a message is a msgpack map")
    _check_structure(obj, 1)
    kind = obj.get("type")
    if type(kind) is not str:
        raise BadFieldError("type is missing or not a string", field="type")
    read = _DECODERS.get(kind)
    if read is None or kind not in (V2_TYPES if v2 else V1_TYPES):
        raise UnknownTypeError(f"unknown message type {kind[:40]!r}", field="type")
    if v2 and kind in _V2_CLIENT_TYPES and len(data) > limits.max_message_bytes:
        raise TooLargeError(f"a {kind} message of {len(data)} bytes")
    return read(_Fields(obj, version=version), limits)


def _check_structure(value: object, depth: int) -> None:
    """MALFORMED for nesting deeper than MAX_DEPTH, a non-str key or an ext value."""
    if type(value) is dict:
        if depth > MAX_DEPTH:
            raise MalformedError(f"nested deeper than {MAX_DEPTH}")
        for key, item in value.items():
            if type(key) is not str:
                raise MalformedError("map keys must be strings")
            _check_structure(item, depth + 1)
    elif type(value) is list:
        if depth > MAX_DEPTH:
            raise MalformedError(f"nested deeper than {MAX_DEPTH}")
        for item in value:
            _check_structure(item, depth + 1)
    elif type(value) not in _LEAVES:  # ExtType, Timestamp
        raise MalformedError("msgpack ext types are not used in v1")


class _Fields:
    """The fields of one map; ``at`` prefixes paths in nested maps (``limits.``)."""

    def __init__(self, m: Map, at: str = "", version: int = PROTOCOL_VERSION) -> None:
        self.m, self.at, self.version = m, at, version

    def has(self, key: str) -> bool:
        return self.m.get(key) is not None  # nil means absent

    def req(self, key: str, check: Callable[..., T], *args: Any) -> T:
        v = self.m.get(key)
        if v is None:
            raise BadFieldError(f"missing field {self.at}{key}", field=self.at + key)
        return check(v, self.at + key, *args)

    def opt(self, key: str, check: Callable[..., T], *args: Any) -> T | None:
        v = self.m.get(key)
        return None if v is None else check(v, self.at + key, *args)


def _bad(path: str, expected: str) -> BadFieldError:
    return BadFieldError(f"{path}: expected {expected}", field=path)


def _int(v: Any, path: str, lo: int, hi: int) -> int:
    if type(v) is not int:  # bool is not an int here, and 7.0 is not either
        raise _bad(path, "an integer")
    if not lo <= v <= hi:
        raise OutOfRangeError(f"{path}={v} outside [{lo}, {hi}]", field=path)
    return v


def _float(v: Any, path: str, lo: float, hi: float) -> float:
    if type(v) is not float and type(v) is not int:
        raise _bad(path, "a number")
    f = float(v)
    if not lo <= f <= hi:  # NaN fails too
        raise OutOfRangeError(f"{path}={f} outside [{lo}, {hi}]", field=path)
    return f


def _time(v: Any, path: str) -> float:
    return _float(v, path, 0.0, MAX_TIME_S)


def _bool(v: Any, path: str) -> bool:
    if type(v) is not bool:
        raise _bad(path, "a boolean")
    return v


def _str(v: Any, path: str, lo: int, hi: int) -> str:
    if type(v) is not str:
        raise _bad(path, "a string")
    n = len(v.encode())
    if not lo <= n <= hi:
        raise OutOfRangeError(f"{path} is {n} bytes, not {lo}..{hi}", field=path)
    return v


def _id(v: Any, path: str, hi: int = MAX_ID_BYTES) -> str:
    s = _str(v, path, 1, hi)
    if _ID.fullmatch(s) is None:
        raise _bad(path, "only A-Z a-z 0-9 _ . : -")
    return s


def _name(v: Any, path: str, hi: int) -> str:
    s = _str(v, path, 1, hi)
    if _CONTROL.search(s) is not None:
        raise _bad(path, "no control characters")
    return s


def _enum(v: Any, path: str, options: tuple[str, ...]) -> str:
    if type(v) is not str or v not in options:
        raise _bad(path, "one of " + ", ".join(options))
    return v


def _array(v: Any, path: str, max_len: int) -> list[Any]:
    if type(v) is not list:
        raise _bad(path, "an array")
    if len(v) > max_len:
        raise OutOfRangeError(f"{path} has {len(v)} items, at most {max_len}", field=path)
    return v


def _bin(v: Any, path: str, size: int) -> bytes:
    if type(v) is not bytes or len(v) != size:
        raise _bad(path, f"a bin of {size} bytes")
    return v


def _numbers(v: Any, path: str, n: int) -> list[float]:
    if type(v) is not list or len(v) != n or any(type(x) not in (int, float) for x in v):
        raise _bad(path, f"an array of {n} numbers")
    return [float(x) for x in v]


def _point(v: Any, path: str) -> tuple[float, float, float]:
    x, y, z = _numbers(v, path, 3)
    if not (abs(x) <= MAX_COORD_M and abs(y) <= MAX_COORD_M and abs(z) <= MAX_COORD_M):
        raise OutOfRangeError(f"{path} not finite or beyond {MAX_COORD_M} m", field=path)
    return x, y, z


def _layout(v: Any, path: str) -> str:
    """``hello.layout``: a named layout or a tracker set (:mod:`posecast_client.sites`)."""
    text = _str(v, path, 1, MAX_LAYOUT_BYTES)
    if text not in LAYOUTS:
        try:
            tracker_set(text)
        except ValueError as exc:
            raise BadFieldError(
                f"layout {text!r}: {exc} (a named layout: {', '.join(LAYOUTS)}, or a tracker set)",
                field=path,
            ) from None
    return text


def _trackers(v: Any, path: str, valid: int) -> tuple[F64, F64]:
    """4 rows ``[px py pz qx qy qz qw]`` -> positions (4, 3), orientations (4, 4).

    Tracked slots are range-checked and their quaternions renormalised exactly as the
    spec writes it; untracked slots are only type-checked and read as origin + identity.
    """
    if type(v) is not list or len(v) != 4:
        raise _bad(path, "an array of 4 trackers")
    return _checked_rows(v, path, valid)


def _sites(v: Any, path: str, valid: int | None) -> tuple[F64, F64, int]:
    """A tracker set's 1 to 10 rows, checked as :func:`_trackers` checks trackers, with
    ``valid`` (``None``: all) a bit mask over them -> ``(positions, orientations, valid)``."""
    if type(v) is not list or not 1 <= len(v) <= MAX_SITES:
        raise _bad(path, f"an array of 1 to {MAX_SITES} sites")
    full = (1 << len(v)) - 1
    if valid is not None and valid > full:
        raise OutOfRangeError(f"valid {valid} has bits beyond the {len(v)} sites", field="valid")
    mask = full if valid is None else valid
    return (*_checked_rows(v, path, mask), mask)


def _checked_rows(v: list[Any], path: str, valid: int) -> tuple[F64, F64]:
    out = np.zeros((len(v), 7))  # (n, 7)
    out[:, 6] = 1.0
    for i, row in enumerate(v):
        at = f"{path}[{i}]"
        px, py, pz, qx, qy, qz, qw = _numbers(row, at, 7)
        if not valid >> i & 1:
            continue
        if not (abs(px) <= MAX_COORD_M and abs(py) <= MAX_COORD_M and abs(pz) <= MAX_COORD_M):
            raise OutOfRangeError(f"{at} position not finite or beyond {MAX_COORD_M} m", field=at)
        if not all(map(math.isfinite, (qx, qy, qz, qw))):
            raise OutOfRangeError(f"{at} orientation not finite", field=at)
        n = math.sqrt(((qx * qx + qy * qy) + qz * qz) + qw * qw)
        if not abs(n - 1.0) <= QUAT_TOLERANCE:
            raise NotNormalisedError(f"{at} orientation has norm {n:.6f}", field=at)
        out[i] = (px, py, pz, qx / n, qy / n, qz / n, qw / n)
    return out[:, :3].copy(), out[:, 3:].copy()


def _members(v: Any, path: str, lim: Limits, version: int) -> tuple[Member, ...]:
    members = []
    for i, item in enumerate(_array(v, path, lim.max_players)):
        if type(item) is not dict:
            raise _bad(f"{path}[{i}]", "a map")
        f = _Fields(item, f"{path}[{i}].")
        player, name = f.req("player", _id), f.req("name", _name, lim.max_name_bytes)
        if version >= PROTOCOL_V2:
            members.append(Member(player, name, f.req("handle", _int, 0, UINT32_MAX),
                                  f.req("skeleton", _bin, SKELETON_BYTES)))  # fmt: skip
        else:
            members.append(Member(player, name))
    return tuple(members)


def _pose_rate(v: Any, path: str) -> float:
    rate = _float(v, path, 0.0, 1000.0)
    if rate not in POSE_RATES_HZ:
        raise OutOfRangeError(f"{path}={rate}: not 60, 30, 20 or 15", field=path)
    return rate


def _forecast(v: Any, path: str) -> float:
    return _float(v, path, 0.0, MAX_FORECAST_MS)


def _limits(v: Any, path: str) -> Limits:
    if type(v) is not dict:
        raise _bad(path, "a map")
    f = _Fields(v, path + ".")
    return Limits(**{k: f.req(k, _int, lo, hi) for k, (lo, hi) in LIMIT_RANGES.items()})


def _hello(f: _Fields, lim: Limits) -> Hello:
    version = f.req("version", _int, -(2**63), 2**64)
    if version != f.version:
        raise VersionUnsupportedError(
            f"version {version} on a posecast.v{f.version} connection", field="version"
        )
    watch = f.opt("watch", _array, lim.max_watch_rooms) or []
    return Hello(
        version=version,
        token=f.req("token", _str, 0, lim.max_token_bytes),
        room=f.req("room", _id, lim.max_room_bytes),
        name=f.req("name", _name, lim.max_name_bytes),
        layout=f.opt("layout", _layout),
        rate_hz=f.opt("rate_hz", _float, 1.0, lim.max_rate_hz),
        watch=tuple(_id(r, f"watch[{i}]", lim.max_room_bytes) for i, r in enumerate(watch)),
        pose_rate_hz=f.opt("pose_rate_hz", _pose_rate) if f.version >= PROTOCOL_V2 else None,
        forecast_ms=f.opt("forecast_ms", _forecast) if f.version >= PROTOCOL_V2 else None,
    )


def _welcome(f: _Fields, lim: Limits) -> Welcome:
    return Welcome(
        version=f.req("version", _int, 1, 255),
        player=f.req("player", _id),
        session=f.req("session", _id),
        role=f.req("role", _enum, ROLES),
        room=f.req("room", _id, lim.max_room_bytes),
        t=f.req("t", _time),
        rate_hz=f.req("rate_hz", _float, 1.0, 1000.0),
        lookahead_frames=f.req("lookahead_frames", _int, 0, 255),
        members=f.req("members", _members, lim, f.version),
        limits=f.req("limits", _limits),
        pose_rate_hz=f.req("pose_rate_hz", _pose_rate) if f.version >= PROTOCOL_V2 else None,
        forecast_ms=f.opt("forecast_ms", _forecast) if f.version >= PROTOCOL_V2 else None,
    )


def _calibrate(f: _Fields, lim: Limits) -> Calibrate:
    tpose = f.opt("tpose", _bool)
    if tpose is False:
        raise _bad("tpose", "true (or tpose absent)")
    if tpose and f.has("height_m"):
        raise BadFieldError("give height_m or tpose, not both", field="tpose")
    if not tpose:
        return Calibrate(height_m=f.req("height_m", _float, MIN_HEIGHT_M, MAX_HEIGHT_M))
    if f.has("sites"):
        if f.has("trackers"):
            raise BadFieldError("give trackers or sites, not both", field="sites")
        pos, quat, _ = f.req("sites", _sites, None)
        return Calibrate(positions=pos, orientations=quat, sites=True)
    pos, quat = f.req("trackers", _trackers, ALL_VALID)
    return Calibrate(positions=pos, orientations=quat)


def _frame(f: _Fields, lim: Limits) -> Frame:
    seq = f.req("seq", _int, 0, UINT32_MAX)
    try:
        t = f.req("t", _time)
        if f.has("sites"):
            if f.has("trackers"):
                raise BadFieldError("give trackers or sites, not both", field="sites")
            mask = f.opt("valid", _int, 0, ALL_SITES_VALID)
            pos, quat, valid = f.req("sites", _sites, mask)
            return Frame(seq, t, pos, quat, valid, sites=True)
        mask = f.opt("valid", _int, 0, ALL_VALID)
        valid = ALL_VALID if mask is None else mask
        pos, quat = f.req("trackers", _trackers, valid)
    except ProtocolError as exc:
        exc.ref_seq = seq
        raise
    return Frame(seq, t, pos, quat, valid)


def _pose(f: _Fields, lim: Limits) -> Pose:
    root = np.array(f.req("root", _point))
    offsets = np.frombuffer(f.req("pos_mm", _bin, POS_BYTES), _I16).reshape(NUM_JOINTS - 1, 3)
    positions = np.empty((NUM_JOINTS, 3))  # (19, 3)
    positions[0] = root
    positions[1:] = root + offsets * POS_UNIT_M
    rot = f.opt("rot", _bin, ROT_BYTES)
    rotations = None
    if rot is not None:
        rotations = np.frombuffer(rot, _I16).reshape(NUM_JOINTS, 4) / ROT_SCALE  # (19, 4)
        norms = np.sqrt((rotations**2).sum(axis=1))
        if not (np.abs(norms - 1.0) <= QUAT_TOLERANCE).all():
            raise NotNormalisedError("a rotation in rot is not unit length", field="rot")
    return Pose(
        player=f.req("player", _id),
        seq=f.req("seq", _int, 0, UINT32_MAX),
        t=f.req("t", _time),
        positions=positions,
        rotations=rotations,
    )


def _selector(f: _Fields, lim: Limits) -> Selector:
    player, kind = f.req("player", _id), f.req("kind", _enum, SELECTOR_KINDS)
    for key in ("joint", "point", "radius_m", "margin_m", "factor"):
        if f.has(key) and key not in _SELECTOR_APPLIES[kind]:
            raise BadFieldError(f"{key} does not apply to a {kind} selector", field=key)
    aimed = kind != "anomaly"
    return Selector(
        player=player,
        kind=kind,
        joint=f.req("joint", _enum, JOINT_NAMES) if aimed else None,
        point=f.req("point", _point) if aimed else None,
        radius_m=f.opt("radius_m", _float, 0.001, 10.0),
        margin_m=f.opt("margin_m", _float, 0.0, 10.0),
        factor=f.opt("factor", _float, 0.1, 100.0),
    )


def _error(f: _Fields, lim: Limits) -> Error:
    code = f.req("code", _str, 0, MAX_STR_BYTES)
    if _CODE.fullmatch(code) is None:  # the pattern also bounds the length: BAD_FIELD
        raise _bad("code", "[A-Z][A-Z0-9_]{0,31}")
    return Error(
        code=code,
        message=f.req("message", _str, 0, lim.max_text_bytes),
        fatal=f.req("fatal", _bool),
        field=f.opt("field", _str, 0, lim.max_text_bytes),
        ref_seq=f.opt("ref_seq", _int, 0, UINT32_MAX),
    )


def _presence(f: _Fields, lim: Limits) -> Presence:
    event = f.req("event", _enum, PRESENCE_EVENTS)
    join = f.version >= PROTOCOL_V2 and event == "join"
    return Presence(
        event,
        f.req("room", _id, lim.max_room_bytes),
        f.req("player", _id),
        f.req("name", _name, lim.max_name_bytes),
        f.req("handle", _int, 0, UINT32_MAX) if join else None,
        f.req("skeleton", _bin, SKELETON_BYTES) if join else None,
    )


def _data(v: Any, path: str) -> bytes:
    if type(v) is not bytes:
        raise _bad(path, "a bin")
    return v


_DECODERS: dict[str, Callable[[_Fields, Limits], Message]] = {
    "hello": _hello,
    "welcome": _welcome,
    "calibrate": _calibrate,
    "frame": _frame,
    "pose": _pose,
    "presence": lambda f, lim: _presence(f, lim),
    "selector": _selector,
    "kick": lambda f, lim: Kick(f.req("player", _id), f.opt("reason", _str, 0, lim.max_text_bytes)),
    "ping": lambda f, lim: Ping(f.req("t0", _time)),
    "pong": lambda f, lim: Pong(f.req("t0", _time), f.req("t1", _time), f.req("t2", _time)),
    "error": _error,
    "bye": lambda f, lim: Bye(f.opt("reason", _str, 0, lim.max_text_bytes)),
    "poses": lambda f, lim: Poses(f.req("t", _time), f.req("data", _data)),
    "skeleton": lambda f, lim: Skeleton(
        f.req("player", _id),
        f.req("handle", _int, 0, UINT32_MAX),
        f.req("skeleton", _bin, SKELETON_BYTES),
    ),
    "pose_rate": lambda f, lim: PoseRate(f.req("rate_hz", _pose_rate)),
    "resync": lambda f, lim: Resync(),
    "forecast": lambda f, lim: Forecast(f.req("ms", _forecast)),
}


# --- encoding ------------------------------------------------------------------------


def encode(msg: Message) -> bytes:
    """The canonical msgpack bytes of ``msg``.

    The message is trusted (build frames with
    :meth:`posecast_client.session.ClientSession.frame`, which checks them), except
    where quantising needs it: a pose joint more than 32.767 m from its pelvis is
    OUT_OF_RANGE, a rotation far from unit length NOT_NORMALISED.
    """
    out: bytes = msgpack.packb(to_wire(msg), use_bin_type=True)
    return out


def to_wire(msg: Message) -> Map:
    """The canonical wire map of ``msg``: keys in spec order, absent optionals left out."""
    values = _ENCODERS[msg.TYPE](msg)
    return {
        "type": msg.TYPE,
        **{k: values[k] for k in FIELDS[msg.TYPE] if values.get(k) is not None},
    }


def _fl(v: float | None) -> float | None:
    return None if v is None else float(v)


def _rows(pos: Any, quat: Any) -> list[list[float]]:
    rows: list[list[float]] = np.hstack([pos, quat]).astype(np.float64).tolist()  # (4, 7)
    return rows


def pos2mm(positions: Any) -> tuple[list[float], bytes]:
    """Pose positions ``(19, 3)`` metres -> ``(root [3] floats, 108 bytes of int16 mm)``."""
    p = np.asarray(positions, dtype=np.float64)
    mm = np.rint((p[1:] - p[0]) / POS_UNIT_M)  # (18, 3)
    if not (np.abs(mm) <= 32767).all():
        raise OutOfRangeError("a joint is more than 32.767 m from the pelvis", field="pos_mm")
    root: list[float] = p[0].tolist()
    return root, mm.astype(_I16).tobytes()


def quat2snorm(rotations: Any) -> bytes:
    """Pose rotations ``(19, 4)`` xyzw -> 152 bytes of int16 ``round(q * 32767)``."""
    s = np.rint(np.asarray(rotations, dtype=np.float64) * ROT_SCALE)  # (19, 4)
    if not (np.abs(s) <= 32767).all():  # NaN fails too
        raise NotNormalisedError("a rotation is not a unit quaternion", field="rot")
    return s.astype(_I16).tobytes()


def _enc_pose(p: Pose) -> Map:
    root, pos_mm = pos2mm(p.positions)
    rot = None if p.rotations is None else quat2snorm(p.rotations)
    return {"player": p.player, "seq": int(p.seq), "t": float(p.t), "root": root,
            "pos_mm": pos_mm, "rot": rot}  # fmt: skip


_ENCODERS: dict[str, Callable[[Any], Map]] = {
    "hello": lambda h: {
        "version": h.version, "token": h.token, "room": h.room, "name": h.name,
        "layout": h.layout, "rate_hz": _fl(h.rate_hz), "watch": list(h.watch) or None,
        "pose_rate_hz": _fl(h.pose_rate_hz), "forecast_ms": _fl(h.forecast_ms),
    },
    "welcome": lambda w: {
        "version": w.version, "player": w.player, "session": w.session, "role": w.role,
        "room": w.room, "t": float(w.t), "rate_hz": float(w.rate_hz),
        "lookahead_frames": w.lookahead_frames,
        "members": [_member(m) for m in w.members],
        "limits": {k: getattr(w.limits, k) for k in LIMIT_RANGES},
        "pose_rate_hz": _fl(w.pose_rate_hz), "forecast_ms": _fl(w.forecast_ms),
    },
    "calibrate": lambda c: (
        {"height_m": float(c.height_m)} if c.positions is None
        else {"tpose": True,
              ("sites" if c.sites else "trackers"): _rows(c.positions, c.orientations)}
    ),
    "frame": lambda f: {
        "seq": int(f.seq), "t": float(f.t),
        ("sites" if f.sites else "trackers"): _rows(f.positions, f.orientations),
        "valid": None if f.valid == (1 << len(f.positions)) - 1 else int(f.valid),
    },
    "pose": _enc_pose,
    "presence": lambda p: {"event": p.event, "room": p.room, "player": p.player, "name": p.name,
                           "handle": p.avatar_id, "skeleton": p.skeleton},
    "selector": lambda s: {
        "player": s.player, "kind": s.kind, "joint": s.joint,
        "point": None if s.point is None else [float(c) for c in s.point],
        "radius_m": _fl(s.radius_m), "margin_m": _fl(s.margin_m), "factor": _fl(s.factor),
    },
    "kick": lambda k: {"player": k.player, "reason": k.reason},
    "ping": lambda p: {"t0": float(p.t0)},
    "pong": lambda p: {"t0": float(p.t0), "t1": float(p.t1), "t2": float(p.t2)},
    "error": lambda e: {"code": e.code, "message": e.message, "fatal": e.fatal,
                        "field": e.field, "ref_seq": e.ref_seq},
    "bye": lambda b: {"reason": b.reason},
    "poses": lambda p: {"t": float(p.t), "data": bytes(p.data)},
    "skeleton": lambda k: {"player": k.player, "handle": k.avatar_id, "skeleton": k.skeleton},
    "pose_rate": lambda p: {"rate_hz": float(p.rate_hz)},
    "resync": lambda r: {},
    "forecast": lambda f: {"ms": float(f.ms)},
}  # fmt: skip


def _member(m: Member) -> Map:
    out: Map = {"player": m.player, "name": m.name}
    if m.avatar_id is not None:
        out["handle"] = m.avatar_id
    if m.skeleton is not None:
        out["skeleton"] = m.skeleton
    return out
