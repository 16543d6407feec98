"""Per message type: a checked wire map -> message, and a message -> its wire map.

:data:`DECODERS` ``[type](fields, limits)`` reads a map that
:func:`posecast_client.codec.decode` has already held to the structural bounds, with
the :mod:`posecast_client.fields` validators (``fields.version`` is the connection's
protocol: v2's ``hello``, ``welcome`` and ``presence`` carry more). :data:`ENCODERS`
``[type](message)`` gives the values of a message's wire fields, floats as Python
floats and absent optionals as ``None``; :func:`posecast_client.codec.to_wire` puts
them in canonical order. Pose quantisation is :mod:`posecast_client.quantize`. Pure,
as the server's twin ``posecast.online.protocol.wire``.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np

from posecast_client.errors import (
    BadFieldError,
    NotNormalisedError,
    ProtocolError,
    VersionUnsupportedError,
)
from posecast_client.fields import (
    CODE_PATTERN,
    SKELETON_BYTES,
    Fields,
    Map,
    as_array,
    as_bin,
    as_bool,
    as_data,
    as_enum,
    as_float,
    as_forecast,
    as_id,
    as_int,
    as_layout,
    as_limits,
    as_members,
    as_name,
    as_point,
    as_pose_rate,
    as_sites,
    as_str,
    as_time,
    as_trackers,
    bad,
)
from posecast_client.protocol import (
    ALL_SITES_VALID,
    ALL_VALID,
    LIMIT_RANGES,
    MAX_HEIGHT_M,
    MAX_STR_BYTES,
    MIN_HEIGHT_M,
    PRESENCE_EVENTS,
    PROTOCOL_V2,
    QUAT_TOLERANCE,
    ROLES,
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
from posecast_client.quantize import POS_BYTES, ROT_BYTES, mm2pos, pos2mm, quat2snorm, snorm2quat
from posecast_client.skeleton import JOINT_NAMES

_SELECTOR_APPLIES = {
    "anomaly": {"factor"},
    "target": {"joint", "point", "margin_m"},
    "obstacle": {"joint", "point", "radius_m"},
}


# --- decoding ------------------------------------------------------------------------


def _hello(f: Fields, lim: Limits) -> Hello:
    version = f.req("version", as_int, -(2**63), 2**64)
    if version != f.version:
        raise VersionUnsupportedError(
            f"version {version} on a posecast.v{f.version} connection", field="version"
        )
    watch = f.opt("watch", as_array, lim.max_watch_rooms) or []
    return Hello(
        version=version,
        token=f.req("token", as_str, 0, lim.max_token_bytes),
        room=f.req("room", as_id, lim.max_room_bytes),
        name=f.req("name", as_name, lim.max_name_bytes),
        layout=f.opt("layout", as_layout),
        rate_hz=f.opt("rate_hz", as_float, 1.0, lim.max_rate_hz),
        watch=tuple(as_id(r, f"watch[{i}]", lim.max_room_bytes) for i, r in enumerate(watch)),
        pose_rate_hz=f.opt("pose_rate_hz", as_pose_rate) if f.version >= PROTOCOL_V2 else None,
        forecast_ms=f.opt("forecast_ms", as_forecast) if f.version >= PROTOCOL_V2 else None,
    )


def _welcome(f: Fields, lim: Limits) -> Welcome:
    return Welcome(
        version=f.req("version", as_int, 1, 255),
        player=f.req("player", as_id),
        session=f.req("session", as_id),
        role=f.req("role", as_enum, ROLES),
        room=f.req("room", as_id, lim.max_room_bytes),
        t=f.req("t", as_time),
        rate_hz=f.req("rate_hz", as_float, 1.0, 1000.0),
        lookahead_frames=f.req("lookahead_frames", as_int, 0, 255),
        members=f.req("members", as_members, lim, f.version),
        limits=f.req("limits", as_limits),
        pose_rate_hz=f.req("pose_rate_hz", as_pose_rate) if f.version >= PROTOCOL_V2 else None,
        forecast_ms=f.opt("forecast_ms", as_forecast) if f.version >= PROTOCOL_V2 else None,
    )


def _calibrate(f: Fields, lim: Limits) -> Calibrate:
    tpose = f.opt("tpose", as_bool)
    if tpose is False:
        raise bad("tpose", "true (or tpose absent)")
    if tpose and f.has("height_m"):
        raise BadFieldError("give height_m or tpose, not both", field="tpose")
    if not tpose:
        return Calibrate(height_m=f.req("height_m", as_float, MIN_HEIGHT_M, MAX_HEIGHT_M))
    if f.has("sites"):
        if f.has("trackers"):
            raise BadFieldError("give trackers or sites, not both", field="sites")
        pos, quat, _ = f.req("sites", as_sites, None)
        return Calibrate(positions=pos, orientations=quat, sites=True)
    pos, quat = f.req("trackers", as_trackers, ALL_VALID)
    return Calibrate(positions=pos, orientations=quat)


def _frame(f: Fields, lim: Limits) -> Frame:
    seq = f.req("seq", as_int, 0, UINT32_MAX)
    try:
        t = f.req("t", as_time)
        if f.has("sites"):
            if f.has("trackers"):
                raise BadFieldError("give trackers or sites, not both", field="sites")
            mask = f.opt("valid", as_int, 0, ALL_SITES_VALID)
            pos, quat, valid = f.req("sites", as_sites, mask)
            return Frame(seq, t, pos, quat, valid, sites=True)
        mask = f.opt("valid", as_int, 0, ALL_VALID)
        valid = ALL_VALID if mask is None else mask
        pos, quat = f.req("trackers", as_trackers, valid)
    except ProtocolError as exc:
        exc.ref_seq = seq
        raise
    return Frame(seq, t, pos, quat, valid)


def _pose(f: Fields, lim: Limits) -> Pose:
    root = np.array(f.req("root", as_point))
    positions = mm2pos(root, f.req("pos_mm", as_bin, POS_BYTES))  # (19, 3)
    rot = f.opt("rot", as_bin, ROT_BYTES)
    rotations = None
    if rot is not None:
        rotations = snorm2quat(rot)  # (19, 4)
        norms = np.sqrt((rotations**2).sum(axis=1))
        if not (np.abs(norms - 1.0) <= QUAT_TOLERANCE).all():
            raise NotNormalisedError("a rotation in rot is not unit length", field="rot")
    return Pose(
        player=f.req("player", as_id),
        seq=f.req("seq", as_int, 0, UINT32_MAX),
        t=f.req("t", as_time),
        positions=positions,
        rotations=rotations,
    )


def _selector(f: Fields, lim: Limits) -> Selector:
    player, kind = f.req("player", as_id), f.req("kind", as_enum, SELECTOR_KINDS)
    for key in ("joint", "point", "radius_m", "margin_m", "factor"):
        if f.has(key) and key not in _SELECTOR_APPLIES[kind]:
            raise BadFieldError(f"{key} does not apply to a {kind} selector", field=key)
    aimed = kind != "anomaly"
    return Selector(
        player=player,
        kind=kind,
        joint=f.req("joint", as_enum, JOINT_NAMES) if aimed else None,
        point=f.req("point", as_point) if aimed else None,
        radius_m=f.opt("radius_m", as_float, 0.001, 10.0),
        margin_m=f.opt("margin_m", as_float, 0.0, 10.0),
        factor=f.opt("factor", as_float, 0.1, 100.0),
    )


def _error(f: Fields, lim: Limits) -> Error:
    code = f.req("code", as_str, 0, MAX_STR_BYTES)
    if CODE_PATTERN.fullmatch(code) is None:  # the pattern also bounds the length: BAD_FIELD
        raise bad("code", "[A-Z][A-Z0-9_]{0,31}")
    return Error(
        code=code,
        message=f.req("message", as_str, 0, lim.max_text_bytes),
        fatal=f.req("fatal", as_bool),
        field=f.opt("field", as_str, 0, lim.max_text_bytes),
        ref_seq=f.opt("ref_seq", as_int, 0, UINT32_MAX),
    )


def _presence(f: Fields, lim: Limits) -> Presence:
    event = f.req("event", as_enum, PRESENCE_EVENTS)
    join = f.version >= PROTOCOL_V2 and event == "join"
    return Presence(
        event,
        f.req("room", as_id, lim.max_room_bytes),
        f.req("player", as_id),
        f.req("name", as_name, lim.max_name_bytes),
        f.req("handle", as_int, 0, UINT32_MAX) if join else None,
        f.req("skeleton", as_bin, SKELETON_BYTES) if join else None,
    )


DECODERS: dict[str, Callable[[Fields, Limits], Message]] = {
    "hello": _hello,
    "welcome": _welcome,
    "calibrate": _calibrate,
    "frame": _frame,
    "pose": _pose,
    "presence": lambda f, lim: _presence(f, lim),
    "selector": _selector,
    "kick": lambda f, lim: Kick(
        f.req("player", as_id), f.opt("reason", as_str, 0, lim.max_text_bytes)
    ),
    "ping": lambda f, lim: Ping(f.req("t0", as_time)),
    "pong": lambda f, lim: Pong(f.req("t0", as_time), f.req("t1", as_time), f.req("t2", as_time)),
    "error": _error,
    "bye": lambda f, lim: Bye(f.opt("reason", as_str, 0, lim.max_text_bytes)),
    "poses": lambda f, lim: Poses(f.req("t", as_time), f.req("data", as_data)),
    "skeleton": lambda f, lim: Skeleton(
        f.req("player", as_id),
        f.req("handle", as_int, 0, UINT32_MAX),
        f.req("skeleton", as_bin, SKELETON_BYTES),
    ),
    "pose_rate": lambda f, lim: PoseRate(f.req("rate_hz", as_pose_rate)),
    "resync": lambda f, lim: Resync(),
    "forecast": lambda f, lim: Forecast(f.req("ms", as_forecast)),
}


# --- encoding ------------------------------------------------------------------------


def _fl(v: float | None) -> float | None:
    return None if v is None else float(v)


def _rows(pos: Any, quat: Any) -> list[list[float]]:
    rows: list[list[float]] = np.hstack([pos, quat]).astype(np.float64).tolist()  # (4, 7)
    return rows


def _enc_pose(p: Pose) -> Map:
    root, pos_mm = pos2mm(p.positions)
    rot = None if p.rotations is None else quat2snorm(p.rotations)
    return {"player": p.player, "seq": int(p.seq), "t": float(p.t), "root": root,
            "pos_mm": pos_mm, "rot": rot}  # fmt: skip


ENCODERS: dict[str, Callable[[Any], Map]] = {
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
