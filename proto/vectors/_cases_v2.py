"""Vectors of what protocol v2 adds: hello, welcome and presence v2, poses (as messages
and as streams of records), skeleton, pose_rate, forecast, resync, and the v2 envelope
bounds.

A *stream* case (in ``poses.json``) is a sequence of ``poses`` messages decoded by one
client in order: ``avatars`` are announced first (handle, player, skeleton), each
message's records update that client's references, and ``expect`` lists, per message,
every record decoded: its handle, seq, flags, root (metres), the 19 items (PELVIS
world rotation, then local rotations, xyzw) and the joint positions FK gives with
the avatar's skeleton. Floats are compared within ``tolerance``. An invalid stream
(``error``, ``field``) fails on its last message, after the earlier ones decoded.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from _writer import invalid, pack, to_json, valid

from posecast.online.protocol import codec, records
from posecast.online.protocol import messages as m
from posecast.online.protocol.records import PoseState, Recon, write_leb128

V2 = m.PROTOCOL_V2
SKELETON = records.skeleton2bytes(records.skeleton_offsets(1.0))  # the reference body
TALL = records.skeleton2bytes(records.skeleton_offsets(1.6 / 1.8))  # a 1.8 m head height


def _v2(name: str, msg: m.Message, description: str, extra: tuple[bytes, ...] = ()) -> Any:
    return valid(name, msg, description, extra, version=V2)


def _bad(
    name: str, data: bytes | dict[str, Any], error: str, description: str, field: str | None = None
) -> Any:
    return invalid(name, data, error, description, field, version=V2)


def hello_cases() -> list[dict[str, Any]]:
    h = m.Hello(2, "tok.en", "arena-7", "Ada")
    base = codec.to_wire(h)
    return [
        _v2("hello_v2", h, "a v2 hello: version 2, the default pose rate"),
        _v2(
            "hello_v2_pose_rate",
            m.Hello(2, "tok.en", "arena-7", "Ada", pose_rate_hz=20.0),
            "a phone asks for 20 poses a second",
        ),
        _v2(
            "hello_v2_forecast",
            m.Hello(2, "tok.en", "arena-7", "Ada", forecast_ms=67.0),
            "a client whose network and render delay is about 67 ms asks for poses that far ahead",
        ),
        _bad(
            "hello_v2_forecast_over_100",
            {**base, "forecast_ms": 150.0},
            "OUT_OF_RANGE",
            "150 ms is past the furthest forecast, 100 ms",
            "forecast_ms",
        ),
        _bad(
            "hello_v2_forecast_negative",
            {**base, "forecast_ms": -1},
            "OUT_OF_RANGE",
            "a negative forecast",
            "forecast_ms",
        ),
        _bad(
            "hello_v2_version_1",
            {**base, "version": 1},
            "VERSION_UNSUPPORTED",
            "version 1 on a posecast.v2 connection",
            "version",
        ),
        _bad(
            "hello_v2_pose_rate_45",
            {**base, "pose_rate_hz": 45.0},
            "OUT_OF_RANGE",
            "45 Hz does not divide the 60 Hz tick",
            "pose_rate_hz",
        ),
        _bad(
            "hello_v2_pose_rate_string",
            {**base, "pose_rate_hz": "30"},
            "BAD_FIELD",
            "a str",
            "pose_rate_hz",
        ),
        _bad(
            "hello_v2_pose_rate_nan",
            {**base, "pose_rate_hz": float("nan")},
            "OUT_OF_RANGE",
            "NaN",
            "pose_rate_hz",
        ),
    ]


def welcome_cases() -> list[dict[str, Any]]:
    members = (m.Member("p-3", "Bea", 0, SKELETON), m.Member("p-4", "Ada", 131, TALL))
    w = m.Welcome(
        2, "p-4", "s-9f", "player", "arena-7", 100.25, 60.0, 10, members, m.Limits(), 30.0
    )
    base = codec.to_wire(w)
    first = dict(base["members"][0])
    no_avatar_id = {k: v for k, v in first.items() if k != "handle"}
    return [
        _v2("welcome_v2", w, "members carry a handle and a skeleton; this client gets 30 Hz"),
        _v2(
            "welcome_v2_forecast",
            m.Welcome(
                2,
                "p-4",
                "s-9f",
                "player",
                "arena-7",
                100.25,
                60.0,
                0,
                members,
                m.Limits(),
                60.0,
                200.0 / 3.0,
            ),
            "this client asked for 67 ms: its poses are forecast 4 ticks (66.67 ms) ahead",
        ),
        _bad(
            "welcome_v2_forecast_over_100",
            {**base, "forecast_ms": 116.7},
            "OUT_OF_RANGE",
            "a forecast past 100 ms",
            "forecast_ms",
        ),
        _bad(
            "welcome_v2_no_handle",
            {**base, "members": [no_avatar_id]},
            "BAD_FIELD",
            "a member without its handle",
            "members[0].handle",
        ),
        _bad(
            "welcome_v2_skeleton_short",
            {**base, "members": [{**first, "skeleton": SKELETON[:-2]}]},
            "BAD_FIELD",
            "106 bytes of skeleton",
            "members[0].skeleton",
        ),
        _bad(
            "welcome_v2_handle_negative",
            {**base, "members": [{**first, "handle": -1}]},
            "OUT_OF_RANGE",
            "handle -1",
            "members[0].handle",
        ),
        _bad(
            "welcome_v2_no_pose_rate",
            {k: v for k, v in base.items() if k != "pose_rate_hz"},
            "BAD_FIELD",
            "no pose_rate_hz",
            "pose_rate_hz",
        ),
    ]


def presence_cases() -> list[dict[str, Any]]:
    join = m.Presence("join", "arena-7", "p-3", "Bea", 5, SKELETON)
    base = codec.to_wire(join)
    return [
        _v2("presence_v2_join", join, "a join carries the handle and the skeleton"),
        _v2(
            "presence_v2_leave",
            m.Presence("leave", "arena-7", "p-3", "Bea"),
            "other events are as in v1",
        ),
        _bad(
            "presence_v2_join_no_skeleton",
            {k: v for k, v in base.items() if k != "skeleton"},
            "BAD_FIELD",
            "a join without a skeleton",
            "skeleton",
        ),
        _bad(
            "presence_v2_join_handle_float",
            {**base, "handle": 5.0},
            "BAD_FIELD",
            "handle 5.0",
            "handle",
        ),
        _bad(
            "presence_v2_join_handle_huge",
            {**base, "handle": 2**32},
            "OUT_OF_RANGE",
            "handle 2**32",
            "handle",
        ),
    ]


def skeleton_cases() -> list[dict[str, Any]]:
    s = m.Skeleton("p-3", 5, TALL)
    base = codec.to_wire(s)
    return [
        _v2("skeleton", s, "p-3 calibrated: FK with these bone offsets from now on"),
        _bad(
            "skeleton_as_array",
            {**base, "skeleton": [0] * 54},
            "BAD_FIELD",
            "ints, not a bin",
            "skeleton",
        ),
        _bad(
            "skeleton_long",
            {**base, "skeleton": TALL + b"\x00\x00"},
            "BAD_FIELD",
            "110 bytes",
            "skeleton",
        ),
        _bad(
            "skeleton_no_handle",
            {k: v for k, v in base.items() if k != "handle"},
            "BAD_FIELD",
            "no handle",
            "handle",
        ),
    ]


def pose_rate_cases() -> list[dict[str, Any]]:
    return [
        _v2("pose_rate_30", m.PoseRate(30.0), "every second tick"),
        _v2("pose_rate_15", m.PoseRate(15.0), "every fourth tick"),
        _bad(
            "pose_rate_25",
            {"type": "pose_rate", "rate_hz": 25.0},
            "OUT_OF_RANGE",
            "25 Hz does not divide 60",
            "rate_hz",
        ),
        _bad(
            "pose_rate_zero", {"type": "pose_rate", "rate_hz": 0}, "OUT_OF_RANGE", "0 Hz", "rate_hz"
        ),
        _bad("pose_rate_missing", {"type": "pose_rate"}, "BAD_FIELD", "no rate_hz", "rate_hz"),
        _bad(
            "pose_rate_bool", {"type": "pose_rate", "rate_hz": True}, "BAD_FIELD", "true", "rate_hz"
        ),
        invalid(
            "pose_rate_v1",
            {"type": "pose_rate", "rate_hz": 30.0},
            "UNKNOWN_TYPE",
            "not a v1 message",
            "type",
        ),
    ]


def forecast_cases() -> list[dict[str, Any]]:
    return [
        _v2("forecast_67", m.Forecast(67.0), "poses forecast 67 ms ahead (4 ticks at 60 Hz)"),
        _v2("forecast_off", m.Forecast(0.0), "0 turns the forecast off"),
        _v2("forecast_100", m.Forecast(100.0), "the furthest a client may ask"),
        _bad(
            "forecast_over_100",
            {"type": "forecast", "ms": 100.5},
            "OUT_OF_RANGE",
            "past 100 ms",
            "ms",
        ),
        _bad("forecast_negative", {"type": "forecast", "ms": -5}, "OUT_OF_RANGE", "-5 ms", "ms"),
        _bad("forecast_nan", {"type": "forecast", "ms": float("nan")}, "OUT_OF_RANGE", "NaN", "ms"),
        _bad("forecast_missing", {"type": "forecast"}, "BAD_FIELD", "no ms", "ms"),
        _bad("forecast_string", {"type": "forecast", "ms": "67"}, "BAD_FIELD", "a str", "ms"),
        invalid(
            "forecast_v1",
            {"type": "forecast", "ms": 67.0},
            "UNKNOWN_TYPE",
            "not a v1 message",
            "type",
        ),
    ]


def resync_cases() -> list[dict[str, Any]]:
    return [
        _v2("resync", m.Resync(), "keyframes of every avatar with the next poses"),
        invalid("resync_v1", {"type": "resync"}, "UNKNOWN_TYPE", "not a v1 message", "type"),
        _bad(
            "resync_huge",
            {"type": "resync", "x": "y" * 4097},
            "TOO_LARGE",
            "an unknown field over the str bound",
        ),
    ]


def envelope_cases() -> list[dict[str, Any]]:
    ping = {"type": "ping", "t0": 1.5}
    big = pack({"type": "poses", "t": 1.5, "data": bytes(16354)})
    assert len(big) == 16385
    return [
        _bad("v2_server_message_too_large", big, "TOO_LARGE", "a poses message of 16385 bytes"),
        _v2(
            "v2_bin_over_256",
            m.Poses(1.5, bytes(range(256)) + bytes(44)),
            "a 300-byte bin: v2 bins may be as long as a server message",
        ),
        _bad(
            "v2_client_message_too_large",
            {**ping, "x": ["y" * 4000, "y" * 4000, "y" * 400]},
            "TOO_LARGE",
            "a ping over max_message_bytes (8192): clients stay within it",
        ),
        _bad(
            "v2_pose_is_v1_only",
            codec.to_wire(m.Pose("p-3", 1, 2.0, np.zeros((19, 3)))),
            "UNKNOWN_TYPE",
            "v2 servers send poses, never pose",
            "type",
        ),
    ]


# --- poses: messages and streams ---------------------------------------------------------


def _motion(frames: int, seed: int, speed: float = 1.0) -> list[tuple[np.ndarray, np.ndarray]]:
    """Smooth made-up motion: (root metres (3,), items (19, 4)) per frame, 60 Hz."""
    rng = np.random.default_rng(seed)
    axes = rng.normal(size=(19, 3))
    axes /= np.linalg.norm(axes, axis=1, keepdims=True)
    amp, freq, phase = rng.uniform(0.1, 0.8, 19), rng.uniform(0.3, 2.0, 19), rng.uniform(0, 6, 19)
    out = []
    for k in range(frames):
        t = k / 60.0 * speed
        angle = amp * np.sin(2 * np.pi * freq * t + phase)  # (19,)
        items = records.rotvec2quat(axes * angle[:, None])
        root = np.array([0.3 + 1.4 * t, 0.95 + 0.02 * np.sin(6 * t), -2.0 + 0.1 * t])
        out.append((root, items))
    return out


def _state(
    player: str, seq: int, root: np.ndarray, items: np.ndarray, limited: bool = False
) -> Any:
    world = records.items2world(items)
    pos = np.zeros((19, 3))
    pos[0] = root
    return PoseState.from_engine(player, seq, 2.0, pos, world, reach_limited=limited)


def _expect(avatar_id: int, rec: records.Record, skeleton: bytes) -> dict[str, Any]:
    r = rec.recon
    return {
        "handle": avatar_id,
        "seq": r.seq,
        "keyframe": rec.keyframe,
        "reach_limited": rec.reach_limited,
        "root": [v * records.ROOT_UNIT_M for v in r.root],
        "items": r.items.tolist(),
        "positions": r.positions(records.bytes2skeleton(skeleton)).tolist(),
    }


def _stream(
    name: str,
    description: str,
    avatars: list[tuple[int, str, bytes]],
    messages: list[bytes],
    error: tuple[str, str] | None = None,
) -> dict[str, Any]:
    """A stream case, decoded here with the server's reference decoder."""
    refs: dict[int, Recon | None] = {h: None for h, _, _ in avatars}
    skel = {h: s for h, _, s in avatars}
    expect = []
    for k, data in enumerate(messages):
        msg = codec.decode(data, version=V2)
        assert isinstance(msg, m.Poses) and codec.encode(msg) == data, name
        last = k == len(messages) - 1
        if error is not None and last:
            try:
                records.decode_records(msg.data, refs)
            except Exception as exc:  # the ProtocolError the case names
                assert (getattr(exc, "code", None), getattr(exc, "field", None)) == error, exc
            else:
                raise AssertionError(f"{name}: decoded")
            break
        expect.append(
            [
                _expect(r.avatar_id, r, skel[r.avatar_id])
                for r in records.decode_records(msg.data, refs)
            ]
        )
    case: dict[str, Any] = {
        "name": name,
        "description": description,
        "versions": [V2],
        "avatars": [{"handle": h, "player": p, "skeleton": to_json(s)} for h, p, s in avatars],
        "messages": [d.hex() for d in messages],
        "expect": expect,
        "tolerance": 1e-9,
    }
    if error is not None:
        case["error"], case["field"] = error
    return case


def _poses(t: float, *recs: bytes) -> bytes:
    return codec.encode(m.Poses(t, b"".join(recs)))


def _encode_run(
    avatar_id: int, player: str, frames: list[tuple[np.ndarray, np.ndarray]], seq0: int
) -> list[bytes]:
    """Records of one avatar, the way the server makes them: a keyframe, then deltas
    (a keyframe again whenever a delta does not fit)."""
    out, ref = [], None
    for k, (root, items) in enumerate(frames):
        s = _state(player, seq0 + k, root, items, limited=k == 3)
        got = None if ref is None else s.delta(ref)
        body, ref = s.keyframe() if got is None else got
        out.append(write_leb128(avatar_id) + body)
    return out


def poses_cases() -> list[dict[str, Any]]:
    walk = _motion(8, seed=1)
    fast = _motion(4, seed=2, speed=40.0)  # residuals too wide for a delta: keyframes
    a = _encode_run(3, "p-3", walk, 1000)
    b = _encode_run(200, "p-200", _motion(8, seed=3), 2**32 - 4)  # a 2-byte avatar id; seq wraps
    still_state = [_state("p-3", 50 + k, walk[0][0], walk[0][1]) for k in range(3)]
    _, ref = still_state[0].keyframe()
    still = [write_leb128(3) + still_state[0].keyframe()[0]]
    for s in still_state[1:]:
        got = s.delta(ref)
        assert got is not None
        body, ref = got
        still.append(write_leb128(3) + body)
    gap = _state("p-3", 1000 + 400, *walk[1])  # 393 frames after a[7]: seq step > 255
    keyframe_a = a[0]
    delta_a = a[1]
    cases: list[dict[str, Any]] = [
        _v2("poses", m.Poses(20.5, a[0] + b[0]), "two keyframes in one message"),
        _v2("poses_empty", m.Poses(20.5, b""), "no records (a server does not send it)"),
        _bad("poses_data_missing", {"type": "poses", "t": 20.5}, "BAD_FIELD", "no data", "data"),
        _bad(
            "poses_data_str",
            {"type": "poses", "t": 20.5, "data": "abc"},
            "BAD_FIELD",
            "a str, not a bin",
            "data",
        ),
        _bad(
            "poses_t_negative",
            {"type": "poses", "t": -1.0, "data": b""},
            "OUT_OF_RANGE",
            "t -1",
            "t",
        ),
        invalid("poses_v1", _poses(20.5, b""), "UNKNOWN_TYPE", "not a v1 message", "type"),
    ]
    skel = [(3, "p-3", SKELETON), (200, "p-200", TALL)]
    cases += [
        _stream(
            "poses_stream_two_avatars",
            "keyframes, then deltas of two avatars per message "
            "(handle 200 takes two LEB128 bytes; its seq wraps; p-3's 4th is reach_limited)",
            skel,
            [_poses(20.5 + k / 60, a[k], b[k]) for k in range(8)],
        ),
        _stream(
            "poses_stream_still",
            "an avatar that does not move: class-0 items",
            skel[:1],
            [_poses(30.0 + k, r) for k, r in enumerate(still)],
        ),
        _stream(
            "poses_stream_fast",
            "motion too fast for a delta: every record a keyframe",
            skel[:1],
            [_poses(40.0 + k, r) for k, r in enumerate(_encode_run(3, "p-3", fast, 7))],
        ),
        _stream(
            "poses_stream_gap",
            "a keyframe after a seq gap of more than 255",
            skel[:1],
            [_poses(50.0, a[0]), _poses(51.0, write_leb128(3) + gap.keyframe()[0])],
        ),
    ]
    h3 = write_leb128(3)
    bad = [
        (
            "poses_stream_unknown_handle",
            "a record for a handle never announced",
            [_poses(1.0, write_leb128(4) + keyframe_a[1:])],
        ),
        (
            "poses_stream_delta_first",
            "a delta before any keyframe of that avatar",
            [_poses(1.0, delta_a)],
        ),
        (
            "poses_stream_reserved_flag",
            "flag bit 2 set",
            [_poses(1.0, h3 + bytes([keyframe_a[1] | 4]) + keyframe_a[2:])],
        ),
        ("poses_stream_keyframe_short", "a keyframe cut short", [_poses(1.0, keyframe_a[:-1])]),
        (
            "poses_stream_delta_short",
            "a delta cut short",
            [_poses(1.0, keyframe_a), _poses(1.1, delta_a[:-3])],
        ),
        (
            "poses_stream_seq_step_zero",
            "a delta with seq step 0",
            [_poses(1.0, keyframe_a), _poses(1.1, delta_a[:2] + b"\x00" + delta_a[3:])],
        ),
        (
            "poses_stream_handle_not_minimal",
            "handle 3 as two LEB128 bytes (83 00)",
            [_poses(1.0, b"\x83\x00" + keyframe_a[1:])],
        ),
        (
            "poses_stream_handle_too_long",
            "a 6-byte LEB128 handle",
            [_poses(1.0, b"\x83\x80\x80\x80\x80\x00" + keyframe_a[1:])],
        ),
        (
            "poses_stream_rotation_reserved_bit",
            "bit 47 of a keyframe rotation set",
            [_poses(1.0, keyframe_a[:23] + bytes([keyframe_a[23] | 0x80]) + keyframe_a[24:])],
        ),
        (
            "poses_stream_root_absurd",
            "a keyframe root x of 1000.1 m",
            [_poses(1.0, keyframe_a[:6] + (10_001_000).to_bytes(4, "little") + keyframe_a[10:])],
        ),
    ]
    for name, description, messages in bad:
        cases.append(_stream(name, description, skel, messages, ("BAD_FIELD", "data")))
    return cases
