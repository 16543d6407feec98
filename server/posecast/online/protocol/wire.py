"""Per message type: the wire map -> dataclass check, and the dataclass -> canonical map.

``DECODERS[version][type] = (known keys, decode)`` and ``ENCODERS[type] = encode``.
v2 (``posecast.v2``) keeps every v1 type but ``pose``, adds ``poses``, ``skeleton``,
``pose_rate``, ``forecast`` and ``resync``, and changes ``hello`` (``version`` 2,
``pose_rate_hz``, ``forecast_ms``), ``welcome`` (members with ``handle`` and
``skeleton``, ``pose_rate_hz``, ``forecast_ms``) and
``presence`` (a ``join`` carries ``handle`` and ``skeleton``); the wire's ``handle``
is the avatar id, ``avatar_id`` in the message classes. A decoder
sees a map already held to the structural bounds, reads every known field with the
:mod:`posecast.online.protocol.fields` validators and ignores the rest. An encoder builds
the map in canonical key order (``type``, then the spec's field order), leaving
absent optionals out and writing every float field as a Python float.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np

from posecast.errors import (
    BadFieldError,
    OutOfRangeError,
    ProtocolError,
    VersionUnsupportedError,
)
from posecast.online.protocol import quantize, records
from posecast.online.protocol.fields import (
    CODE_PATTERN,
    Map,
    as_bin,
    as_bool,
    as_enum,
    as_float,
    as_id,
    as_int,
    as_list,
    as_map,
    as_name,
    as_point,
    as_sites,
    as_str,
    as_trackers,
)
from posecast.online.protocol.messages import (
    ALL_TRACKERS_VALID,
    LIMIT_RANGES,
    MAX_BIN_BYTES_V2,
    MAX_FORECAST_MS,
    MAX_HEIGHT_M,
    MAX_ID_BYTES,
    MAX_LAYOUT_BYTES,
    MAX_LOOKAHEAD_FRAMES,
    MAX_TIME_S,
    MIN_HEIGHT_M,
    POSE_RATES_HZ,
    PRESENCE_EVENTS,
    PROTOCOL_V2,
    PROTOCOL_VERSION,
    ROLES,
    SELECTOR_KINDS,
    UINT32_MAX,
    V1_TYPES,
    V2_TYPES,
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
from posecast.skeleton import JOINT_NAMES
from posecast.tracking.layouts import Layout, PlayerLayout, parse_layout
from posecast.tracking.sites import NUM_SITES, TrackerSetError

NAMED_LAYOUTS = (Layout.HMD3_WAIST.value, Layout.HMD3.value)
ALL_SITES_VALID = (1 << NUM_SITES) - 1

_T = (0.0, MAX_TIME_S)
_SELECTOR_FIELDS = {
    "anomaly": ("factor",),
    "target": ("joint", "point", "margin_m"),
    "obstacle": ("joint", "point", "radius_m"),
}


def _has(m: Map, key: str) -> bool:
    return m.get(key) is not None  # nil reads as absent


def _ids(m: Map, key: str, max_len: int, max_bytes: int) -> tuple[str, ...]:
    if not _has(m, key):
        return ()
    items = as_list(m, key, max_len)
    return tuple(as_id({f"{key}[{i}]": v}, f"{key}[{i}]", max_bytes) for i, v in enumerate(items))


def _text(m: Map, key: str, lim: Limits) -> str | None:
    return as_str(m, key, lim.max_text_bytes, min_bytes=0) if _has(m, key) else None


def _pose_rate(m: Map, key: str) -> float:
    """A v2 pose rate: a number equal to one of 60, 30, 20, 15 (else OUT_OF_RANGE)."""
    v = as_float(m, key, 0.0, 1000.0)  # BAD_FIELD for a non-number, OUT_OF_RANGE for NaN
    if v not in POSE_RATES_HZ:
        raise OutOfRangeError(f"{key}={v} is not one of 60, 30, 20, 15", field=key)
    return v


def _forecast(m: Map, key: str) -> float:
    """A v2 forecast horizon: milliseconds in [0, 100] (else OUT_OF_RANGE)."""
    return as_float(m, key, 0.0, MAX_FORECAST_MS)


def _avatar_id(m: Map, key: str, at: str = "") -> int:
    return as_int(m, key, 0, records.MAX_AVATAR_ID, at=at)


def _skeleton(m: Map, key: str, at: str = "") -> bytes:
    return as_bin(m, key, records.SKELETON_BYTES, at=at)


def _hello(m: Map, lim: Limits, v: int = PROTOCOL_VERSION) -> Hello:
    version = m.get("version")
    if type(version) is not int:
        raise BadFieldError("field version must be an integer", field="version")
    if version != v:
        raise VersionUnsupportedError(
            f"version {version} is not supported on this connection (posecast.v{v})",
            field="version",
        )
    rate = _pose_rate(m, "pose_rate_hz") if v >= PROTOCOL_V2 and _has(m, "pose_rate_hz") else None
    ahead = _forecast(m, "forecast_ms") if v >= PROTOCOL_V2 and _has(m, "forecast_ms") else None
    return Hello(
        version=version,
        token=as_str(m, "token", lim.max_token_bytes, min_bytes=0),
        room=as_id(m, "room", lim.max_room_bytes),
        name=as_name(m, "name", lim.max_name_bytes),
        layout=_layout(m) if _has(m, "layout") else None,
        rate_hz=as_float(m, "rate_hz", 1.0, lim.max_rate_hz) if _has(m, "rate_hz") else None,
        watch=_ids(m, "watch", lim.max_watch_rooms, lim.max_room_bytes),
        pose_rate_hz=rate,
        forecast_ms=ahead,
    )


def _layout(m: Map) -> PlayerLayout:
    text = as_str(m, "layout", MAX_LAYOUT_BYTES)
    try:
        return parse_layout(text)
    except TrackerSetError as exc:
        raise BadFieldError(
            f"layout {text!r}: {exc} (a named layout: {', '.join(NAMED_LAYOUTS)}, or a "
            "tracker set such as head,left_hand,right_hand,waist)",
            field="layout",
        ) from None


def _welcome(m: Map, lim: Limits, v: int = PROTOCOL_VERSION) -> Welcome:
    members = []
    for i, item in enumerate(as_list(m, "members", lim.max_players)):
        at = f"members[{i}]."
        if type(item) is not dict:
            raise BadFieldError(f"members[{i}]: expected a map", field=f"members[{i}]")
        player = as_id(item, "player", MAX_ID_BYTES, at=at)
        name = as_name(item, "name", lim.max_name_bytes, at=at)
        if v >= PROTOCOL_V2:
            members.append(Member(player, name, _avatar_id(item, "handle", at),
                                  _skeleton(item, "skeleton", at)))  # fmt: skip
        else:
            members.append(Member(player, name))
    lm = as_map(m, "limits")
    limits = Limits(
        **{k: as_int(lm, k, lo, hi, at="limits.") for k, (lo, hi) in LIMIT_RANGES.items()}
    )
    return Welcome(
        version=as_int(m, "version", 1, 255),
        player=as_id(m, "player", MAX_ID_BYTES),
        session=as_id(m, "session", MAX_ID_BYTES),
        role=as_enum(m, "role", ROLES),
        room=as_id(m, "room", lim.max_room_bytes),
        t=as_float(m, "t", *_T),
        rate_hz=as_float(m, "rate_hz", 1.0, 1000.0),
        lookahead_frames=as_int(m, "lookahead_frames", 0, MAX_LOOKAHEAD_FRAMES),
        members=tuple(members),
        limits=limits,
        pose_rate_hz=_pose_rate(m, "pose_rate_hz") if v >= PROTOCOL_V2 else None,
        forecast_ms=(
            _forecast(m, "forecast_ms") if v >= PROTOCOL_V2 and _has(m, "forecast_ms") else None
        ),
    )


def _calibrate(m: Map, lim: Limits) -> Calibrate:
    has_height, has_tpose = _has(m, "height_m"), _has(m, "tpose")
    if has_tpose and not as_bool(m, "tpose"):
        raise BadFieldError("tpose, when present, must be true", field="tpose")
    if has_height and has_tpose:
        raise BadFieldError("give height_m or tpose, not both", field="tpose")
    if has_height:
        return Calibrate(height_m=as_float(m, "height_m", MIN_HEIGHT_M, MAX_HEIGHT_M))
    if not has_tpose:
        raise BadFieldError("calibrate needs height_m or tpose: true", field="height_m")
    if _has(m, "sites"):
        if _has(m, "trackers"):
            raise BadFieldError("give trackers or sites, not both", field="sites")
        pos, quat, _ = as_sites(m, "sites", None)
        return Calibrate(pos=pos, quat=quat, sites=True)
    pos, quat = as_trackers(m, "trackers")
    return Calibrate(pos=pos, quat=quat)


def _frame(m: Map, lim: Limits) -> Frame:
    seq = as_int(m, "seq", 0, UINT32_MAX)
    try:
        t = as_float(m, "t", *_T)
        if _has(m, "sites"):
            if _has(m, "trackers"):
                raise BadFieldError("give trackers or sites, not both", field="sites")
            mask = as_int(m, "valid", 0, ALL_SITES_VALID) if _has(m, "valid") else None
            pos, quat, valid = as_sites(m, "sites", mask)
            return Frame(seq, t, pos, quat, valid, sites=True)
        valid = (
            as_int(m, "valid", 0, ALL_TRACKERS_VALID) if _has(m, "valid") else ALL_TRACKERS_VALID
        )
        pos, quat = as_trackers(m, "trackers", valid)
    except ProtocolError as exc:
        exc.ref_seq = seq
        raise
    return Frame(seq, t, pos, quat, valid)


def _pose(m: Map, lim: Limits) -> Pose:
    root = as_point(m, "root")
    rot = as_bin(m, "rot", quantize.ROT_BYTES) if _has(m, "rot") else None
    return Pose(
        player=as_id(m, "player", MAX_ID_BYTES),
        seq=as_int(m, "seq", 0, UINT32_MAX),
        t=as_float(m, "t", *_T),
        positions=quantize.mm2pos(root, as_bin(m, "pos_mm", quantize.POS_BYTES)),
        rotations=None if rot is None else quantize.snorm2quat(rot),
    )


def _presence(m: Map, lim: Limits, v: int = PROTOCOL_VERSION) -> Presence:
    event = as_enum(m, "event", PRESENCE_EVENTS)
    v2_join = v >= PROTOCOL_V2 and event == "join"
    return Presence(
        event=event,
        room=as_id(m, "room", lim.max_room_bytes),
        player=as_id(m, "player", MAX_ID_BYTES),
        name=as_name(m, "name", lim.max_name_bytes),
        avatar_id=_avatar_id(m, "handle") if v2_join else None,
        skeleton=_skeleton(m, "skeleton") if v2_join else None,
    )


def _selector(m: Map, lim: Limits) -> Selector:
    player = as_id(m, "player", MAX_ID_BYTES)
    kind = as_enum(m, "kind", SELECTOR_KINDS)
    for key in ("joint", "point", "radius_m", "margin_m", "factor"):
        if _has(m, key) and key not in _SELECTOR_FIELDS[kind]:
            raise BadFieldError(f"{key} does not apply to a {kind} selector", field=key)
    aimed = kind != "anomaly"
    return Selector(
        player=player,
        kind=kind,
        joint=as_enum(m, "joint", JOINT_NAMES) if aimed else None,
        point=as_point(m, "point") if aimed else None,
        radius_m=as_float(m, "radius_m", 0.001, 10.0) if _has(m, "radius_m") else None,
        margin_m=as_float(m, "margin_m", 0.0, 10.0) if _has(m, "margin_m") else None,
        factor=as_float(m, "factor", 0.1, 100.0) if _has(m, "factor") else None,
    )


def _error(m: Map, lim: Limits) -> Error:
    code = as_str(m, "code", 32)
    if CODE_PATTERN.fullmatch(code) is None:
        raise BadFieldError("code must be upper-case letters, digits and _", field="code")
    return Error(
        code=code,
        message=as_str(m, "message", lim.max_text_bytes, min_bytes=0),
        fatal=as_bool(m, "fatal"),
        field=_text(m, "field", lim),
        ref_seq=as_int(m, "ref_seq", 0, UINT32_MAX) if _has(m, "ref_seq") else None,
    )


def _opt(d: Map, **fields: Any) -> Map:
    d.update((k, v) for k, v in fields.items() if v is not None)
    return d


def _trackers(pos: Any, quat: Any) -> list[list[float]]:
    rows: list[list[float]] = np.hstack([pos, quat]).astype(np.float64).tolist()
    return rows


def _fl(v: float | None) -> float | None:
    return None if v is None else float(v)


def _enc_welcome(w: Welcome) -> Map:
    return {
        "type": "welcome",
        "version": w.version,
        "player": w.player,
        "session": w.session,
        "role": w.role,
        "room": w.room,
        "t": float(w.t),
        "rate_hz": float(w.rate_hz),
        "lookahead_frames": w.lookahead_frames,
        "members": [_member(p) for p in w.members],
        "limits": {k: getattr(w.limits, k) for k in LIMIT_RANGES},
        **({} if w.pose_rate_hz is None else {"pose_rate_hz": float(w.pose_rate_hz)}),
        **({} if w.forecast_ms is None else {"forecast_ms": float(w.forecast_ms)}),
    }


def _member(p: Member) -> Map:
    return _opt({"player": p.player, "name": p.name}, handle=p.avatar_id, skeleton=p.skeleton)


def _enc_pose(p: Pose) -> Map:
    root, pos_mm = quantize.pos2mm(p.positions)
    rot = None if p.rotations is None else quantize.quat2snorm(p.rotations)
    return pose_map(p.player, p.seq, float(p.t), root, pos_mm, rot)


def pose_map(
    player: str, seq: int, t: float, root: list[float], pos_mm: bytes, rot: bytes | None
) -> Map:
    """A quantised ``pose``'s wire map, keys in canonical order (``rot`` when given)."""
    d: Map = {"type": "pose", "player": player, "seq": seq, "t": t, "root": root}
    d["pos_mm"] = pos_mm
    if rot is not None:
        d["rot"] = rot
    return d


_ENC: dict[type[Any], Callable[[Any], Map]] = {
    Hello: lambda h: _opt(
        {"type": "hello", "version": h.version, "token": h.token, "room": h.room, "name": h.name},
        layout=None if h.layout is None else str(h.layout),
        rate_hz=_fl(h.rate_hz),
        watch=list(h.watch) or None,
        pose_rate_hz=_fl(h.pose_rate_hz),
        forecast_ms=_fl(h.forecast_ms),
    ),
    Welcome: _enc_welcome,
    Calibrate: lambda c: (
        {"type": "calibrate", "height_m": float(c.height_m)}
        if c.pos is None
        else {
            "type": "calibrate",
            "tpose": True,
            ("sites" if c.sites else "trackers"): _trackers(c.pos, c.quat),
        }
    ),
    Frame: lambda f: _opt(
        {
            "type": "frame",
            "seq": f.seq,
            "t": float(f.t),
            ("sites" if f.sites else "trackers"): _trackers(f.pos, f.quat),
        },
        valid=None if f.valid == (1 << len(f.pos)) - 1 else f.valid,
    ),
    Pose: _enc_pose,
    Presence: lambda p: _opt(
        {"type": "presence", "event": p.event, "room": p.room, "player": p.player, "name": p.name},
        handle=p.avatar_id,
        skeleton=p.skeleton,
    ),
    Poses: lambda p: {"type": "poses", "t": float(p.t), "data": bytes(p.data)},
    Skeleton: lambda k: {
        "type": "skeleton",
        "player": k.player,
        "handle": k.avatar_id,
        "skeleton": k.skeleton,
    },
    PoseRate: lambda p: {"type": "pose_rate", "rate_hz": float(p.rate_hz)},
    Resync: lambda r: {"type": "resync"},
    Forecast: lambda f: {"type": "forecast", "ms": float(f.ms)},
    Selector: lambda s: _opt(
        {"type": "selector", "player": s.player, "kind": s.kind},
        joint=s.joint,
        point=None if s.point is None else [float(v) for v in s.point],
        radius_m=_fl(s.radius_m),
        margin_m=_fl(s.margin_m),
        factor=_fl(s.factor),
    ),
    Kick: lambda k: _opt({"type": "kick", "player": k.player}, reason=k.reason),
    Ping: lambda p: {"type": "ping", "t0": float(p.t0)},
    Pong: lambda p: {"type": "pong", "t0": float(p.t0), "t1": float(p.t1), "t2": float(p.t2)},
    Error: lambda e: _opt(
        {"type": "error", "code": e.code, "message": e.message, "fatal": e.fatal},
        field=e.field,
        ref_seq=e.ref_seq,
    ),
    Bye: lambda b: _opt({"type": "bye"}, reason=b.reason),
}
ENCODERS: dict[str, Callable[[Any], Map]] = {cls.TYPE: fn for cls, fn in _ENC.items()}

_Dec = Callable[[Map, Limits, int], Message]
_DEC: dict[type[Message], tuple[tuple[str, ...], _Dec]] = {
    Hello: (
        (
            "version",
            "token",
            "room",
            "name",
            "layout",
            "rate_hz",
            "watch",
            "pose_rate_hz",
            "forecast_ms",
        ),
        _hello,
    ),
    Welcome: (
        (
            "version",
            "player",
            "session",
            "role",
            "room",
            "t",
            "rate_hz",
            "lookahead_frames",
            "members",
            "limits",
            "pose_rate_hz",
            "forecast_ms",
        ),
        _welcome,
    ),
    Calibrate: (("height_m", "tpose", "trackers", "sites"), lambda m, lim, v: _calibrate(m, lim)),
    Frame: (("seq", "t", "trackers", "sites", "valid"), lambda m, lim, v: _frame(m, lim)),
    Pose: (("player", "seq", "t", "root", "pos_mm", "rot"), lambda m, lim, v: _pose(m, lim)),
    Presence: (("event", "room", "player", "name", "handle", "skeleton"), _presence),
    Selector: (
        ("player", "kind", "joint", "point", "radius_m", "margin_m", "factor"),
        lambda m, lim, v: _selector(m, lim),
    ),
    Kick: (
        ("player", "reason"),
        lambda m, lim, v: Kick(as_id(m, "player", MAX_ID_BYTES), _text(m, "reason", lim)),
    ),
    Ping: (("t0",), lambda m, lim, v: Ping(as_float(m, "t0", *_T))),
    Pong: (
        ("t0", "t1", "t2"),
        lambda m, lim, v: Pong(
            as_float(m, "t0", *_T), as_float(m, "t1", *_T), as_float(m, "t2", *_T)
        ),
    ),
    Error: (("code", "message", "fatal", "field", "ref_seq"), lambda m, lim, v: _error(m, lim)),
    Bye: (("reason",), lambda m, lim, v: Bye(_text(m, "reason", lim))),
    Poses: (
        ("t", "data"),
        lambda m, lim, v: Poses(as_float(m, "t", *_T), _data(m)),
    ),
    Skeleton: (
        ("player", "handle", "skeleton"),
        lambda m, lim, v: Skeleton(
            as_id(m, "player", MAX_ID_BYTES), _avatar_id(m, "handle"), _skeleton(m, "skeleton")
        ),
    ),
    PoseRate: (("rate_hz",), lambda m, lim, v: PoseRate(_pose_rate(m, "rate_hz"))),
    Resync: ((), lambda m, lim, v: Resync()),
    Forecast: (("ms",), lambda m, lim, v: Forecast(_forecast(m, "ms"))),
}


def _data(m: Map) -> bytes:
    v = m.get("data")
    if type(v) is not bytes:
        raise BadFieldError("data: expected a bin", field="data")
    if len(v) > MAX_BIN_BYTES_V2:  # pragma: no cover - the structural bound comes first
        raise OutOfRangeError("data is too long", field="data")
    return v


# Spec field order per type (canonical key order after "type"), and the decoders.
FIELD_ORDER: dict[str, tuple[str, ...]] = {cls.TYPE: keys for cls, (keys, _) in _DEC.items()}
_ALL: dict[str, tuple[frozenset[str], _Dec]] = {
    cls.TYPE: (frozenset(("type", *keys)), fn) for cls, (keys, fn) in _DEC.items()
}
# The fields each version knows (v1 never learns the v2 fields: they are unknown there).
_V1_FIELDS = {"hello": ("pose_rate_hz", "forecast_ms"), "welcome": ("pose_rate_hz", "forecast_ms"),
              "presence": ("handle", "skeleton")}  # fmt: skip
DECODERS: dict[int, dict[str, tuple[frozenset[str], _Dec]]] = {
    PROTOCOL_VERSION: {
        k: (keys - frozenset(_V1_FIELDS.get(k, ())), fn)
        for k, (keys, fn) in _ALL.items()
        if k in V1_TYPES
    },
    PROTOCOL_V2: {k: entry for k, entry in _ALL.items() if k in V2_TYPES},
}
FIELD_ORDER_V1 = {
    k: tuple(f for f in keys if f not in _V1_FIELDS.get(k, ()))
    for k, keys in FIELD_ORDER.items()
    if k in V1_TYPES
}
