"""Vectors of the envelope and the session messages (hello .. bye, not motion)."""

from __future__ import annotations

from dataclasses import replace
from typing import Any

from _writer import Raw, invalid, pack, valid

from posecast.online.protocol import codec
from posecast.online.protocol import messages as m
from posecast.tracking.sites import TrackerSet


def _padded_ping(size: int) -> bytes:
    """A ping with an unknown field of strings, ``size`` bytes in all."""
    pad = ["y" * 128] * 62
    for n in range(256):
        data = pack({"type": "ping", "t0": 1.5, "x": [*pad, "y" * n]})
        if len(data) == size:
            return data
    raise AssertionError(size)


def envelope_cases() -> list[dict[str, Any]]:
    ping = pack({"type": "ping", "t0": 1.5})
    deep: Any = 1
    for _ in range(8):  # depth 9 counting the root map
        deep = [deep]
    return [
        invalid("empty", b"", "MALFORMED", "zero bytes"),
        invalid("never_used_byte", b"\xc1", "MALFORMED", "0xc1 is never valid msgpack"),
        invalid("json_text", b'{"type":"ping","t0":1.5}', "MALFORMED", "JSON, not msgpack"),
        invalid("truncated", ping[:-3], "MALFORMED", "a ping cut short"),
        invalid("trailing_bytes", ping + b"\x00", "MALFORMED", "two msgpack values"),
        invalid("not_a_map_array", ["ping", 1.5], "MALFORMED", "root is an array"),
        invalid("not_a_map_string", "ping", "MALFORMED", "root is a string"),
        invalid("not_a_map_nil", None, "MALFORMED", "root is nil"),
        invalid("missing_type", {"t0": 1.5}, "BAD_FIELD", "no type key", "type"),
        invalid("nil_type", {"type": None, "t0": 1.5}, "BAD_FIELD", "type is nil", "type"),
        invalid("type_not_string", {"type": 3, "t0": 1.5}, "BAD_FIELD", "type is an int", "type"),
        invalid("type_as_bin", {"type": b"ping", "t0": 1.5}, "BAD_FIELD", "type is a bin", "type"),
        invalid("unknown_type", {"type": "teleport"}, "UNKNOWN_TYPE", "no such type", "type"),
        invalid(
            "type_wrong_case",
            {"type": "PING", "t0": 1.5},
            "UNKNOWN_TYPE",
            "types are lower case",
            "type",
        ),
        invalid("int_key", {1: 2, "type": "ping", "t0": 1.5}, "MALFORMED", "an int map key"),
        invalid("bin_key", {b"k": 2, "type": "ping", "t0": 1.5}, "MALFORMED", "a bin map key"),
        invalid(
            "nested_bin_key",
            {"type": "ping", "t0": 1.5, "x": {b"k": 1}},
            "MALFORMED",
            "a bin key inside an unknown field",
        ),
        invalid(
            "ext_in_unknown_field",
            {"type": "ping", "t0": 1.5, "x": Raw(b"\xd4\x05\x00")},
            "MALFORMED",
            "ext types are not used, not even in unknown fields",
        ),
        invalid(
            "timestamp_ext",
            {"type": "ping", "t0": Raw(b"\xd6\xff\x00\x00\x00\x01")},
            "MALFORMED",
            "the msgpack timestamp extension",
        ),
        invalid(
            "invalid_utf8",
            {"type": "ping", "t0": 1.5, "x": Raw(b"\xa2\xff\xfe")},
            "MALFORMED",
            "a str that is not UTF-8",
        ),
        invalid(
            "deep_nesting",
            {"type": "ping", "t0": 1.5, "x": deep},
            "MALFORMED",
            "9 levels of maps/arrays (the limit is 8, the root map counts)",
        ),
        invalid(
            "deep_nesting_with_bad_field",
            {"type": "ping", "t0": deep},
            "MALFORMED",
            "structure is checked before fields: too deep wins over BAD_FIELD",
        ),
        invalid("very_deep_nesting", b"\x91" * 3000 + b"\xc0", "MALFORMED", "3000 nested arrays"),
        invalid(
            "too_large",
            _padded_ping(8193),
            "TOO_LARGE",
            "8193 bytes, one over the default max_message_bytes",
        ),
        invalid(
            "huge_array",
            {"type": "ping", "t0": 1.5, "x": [0] * 65},
            "TOO_LARGE",
            "an array of 65 (the limit is 64)",
        ),
        invalid(
            "huge_array_header",
            b"\x82\xa4type\xa4ping\xa1x\xdd\xff\xff\xff\xff",
            "TOO_LARGE",
            "an array32 header claiming 2**32 - 1 items (refuse before allocating)",
        ),
        invalid(
            "huge_map",
            {"type": "ping", "t0": 1.5, **{f"k{i}": i for i in range(31)}},
            "TOO_LARGE",
            "a map of 33 entries (the limit is 32)",
        ),
        invalid(
            "huge_string",
            {"type": "ping", "t0": 1.5, "x": "y" * 4097},
            "TOO_LARGE",
            "a str of 4097 bytes (the limit is 4096)",
        ),
        invalid(
            "huge_bin",
            {"type": "ping", "t0": 1.5, "x": b"\x00" * 257},
            "TOO_LARGE",
            "a bin of 257 bytes (the limit is 256)",
        ),
    ]


SET_IMU = "head,left_hand,right_hand,waist,left_foot:imu,right_foot:imu"


def hello_cases() -> list[dict[str, Any]]:
    base = {"type": "hello", "version": 1, "token": "tok", "room": "lobby", "name": "Ada"}
    hello = m.Hello(1, "tok", "lobby", "Ada")
    return [
        valid("hello_minimal", hello, "required fields only (the server takes hmd3+waist, 60 Hz)"),
        valid(
            "hello_player",
            m.Hello(1, "eyJ2IjoxfQ.c2ln", "arena-7", "Ada", "hmd3+waist", 72.0),
            "a player's hello with layout and rate",
        ),
        valid(
            "hello_hmd3", m.Hello(1, "t", "lobby", "Ada", "hmd3"), "a reserved layout still decodes"
        ),
        valid(
            "hello_backend",
            m.Hello(1, "t", "arena-7", "director", watch=("arena-8", "arena-9")),
            "a backend watching two more rooms",
        ),
        valid("hello_unicode_name", m.Hello(1, "", "lobby", "Zoë 🎮"), "UTF-8 name, empty token"),
        valid(
            "hello_name_at_limit",
            m.Hello(1, "t", "lobby", "🎮" * 16),
            "64 bytes of name (16 code points, 32 UTF-16 units)",
        ),
        invalid("hello_version_2", {**base, "version": 2}, "VERSION_UNSUPPORTED", "v2", "version"),
        invalid("hello_version_0", {**base, "version": 0}, "VERSION_UNSUPPORTED", "v0", "version"),
        invalid("hello_version_string", {**base, "version": "1"}, "BAD_FIELD", "a str", "version"),
        invalid("hello_version_float", {**base, "version": 1.0}, "BAD_FIELD", "a float", "version"),
        invalid(
            "hello_missing_token",
            {k: v for k, v in base.items() if k != "token"},
            "BAD_FIELD",
            "no token",
            "token",
        ),
        invalid("hello_token_int", {**base, "token": 5}, "BAD_FIELD", "token is an int", "token"),
        invalid(
            "hello_missing_room",
            {k: v for k, v in base.items() if k != "room"},
            "BAD_FIELD",
            "no room",
            "room",
        ),
        invalid(
            "hello_room_space",
            {**base, "room": "my room"},
            "BAD_FIELD",
            "a space in a room",
            "room",
        ),
        invalid(
            "hello_room_too_long",
            {**base, "room": "r" * 65},
            "OUT_OF_RANGE",
            "65-byte room",
            "room",
        ),
        invalid("hello_room_empty", {**base, "room": ""}, "OUT_OF_RANGE", "empty room", "room"),
        invalid("hello_name_empty", {**base, "name": ""}, "OUT_OF_RANGE", "empty name", "name"),
        invalid(
            "hello_name_too_long", {**base, "name": "a" * 65}, "OUT_OF_RANGE", "65 bytes", "name"
        ),
        invalid(
            "hello_name_too_long_utf8",
            {**base, "name": "🎮" * 17},
            "OUT_OF_RANGE",
            "17 code points but 68 UTF-8 bytes: lengths are bytes",
            "name",
        ),
        invalid("hello_name_control", {**base, "name": "a\nb"}, "BAD_FIELD", "a newline", "name"),
        invalid(
            "hello_layout_unknown",
            {**base, "layout": "hmd4"},
            "BAD_FIELD",
            "no such layout",
            "layout",
        ),
        valid(
            "hello_tracker_set",
            m.Hello(1, "t", "lobby", "Ada", TrackerSet.parse(SET_IMU)),
            "a tracker set: sites in wire order, an inertial one suffixed :imu",
        ),
        invalid(
            "hello_set_no_right_hand",
            {**base, "layout": "head,left_hand"},
            "BAD_FIELD",
            "a set without its right hand",
            "layout",
        ),
        invalid(
            "hello_set_unknown_site",
            {**base, "layout": "head,left_hand,right_hand,tail"},
            "BAD_FIELD",
            "no such site",
            "layout",
        ),
        invalid(
            "hello_set_duplicate",
            {**base, "layout": "head,left_hand,right_hand,waist,waist"},
            "BAD_FIELD",
            "a site listed twice",
            "layout",
        ),
        invalid(
            "hello_set_inertial_head",
            {**base, "layout": "head:imu,left_hand,right_hand"},
            "BAD_FIELD",
            "the head as an IMU",
            "layout",
        ),
        invalid(
            "hello_layout_too_long",
            {**base, "layout": "head," * 30 + "left_hand"},
            "OUT_OF_RANGE",
            "a 159-byte layout (at most 128)",
            "layout",
        ),
        invalid("hello_rate_zero", {**base, "rate_hz": 0.0}, "OUT_OF_RANGE", "0 Hz", "rate_hz"),
        invalid(
            "hello_rate_too_high", {**base, "rate_hz": 121}, "OUT_OF_RANGE", "121 Hz", "rate_hz"
        ),
        invalid("hello_rate_string", {**base, "rate_hz": "60"}, "BAD_FIELD", "a str", "rate_hz"),
        invalid("hello_watch_not_array", {**base, "watch": "arena"}, "BAD_FIELD", "a str", "watch"),
        invalid(
            "hello_watch_too_many",
            {**base, "watch": [f"r{i}" for i in range(17)]},
            "OUT_OF_RANGE",
            "17 rooms (the limit is 16)",
            "watch",
        ),
        invalid(
            "hello_watch_bad_room",
            {**base, "watch": ["ok", "no way"]},
            "BAD_FIELD",
            "bad room",
            "watch[1]",
        ),
    ]


def welcome_cases() -> list[dict[str, Any]]:
    w = m.Welcome(
        1,
        "p-17",
        "s-5f3a",
        "player",
        "arena-7",
        1234.5,
        60.0,
        10,
        (m.Member("p-3", "Bea"), m.Member("p-17", "Ada")),
        m.Limits(),
    )
    base = codec.to_wire(w)
    return [
        valid("welcome_player", w, "a player joins a room of two (itself included)"),
        valid(
            "welcome_spectator_lowered_limits",
            replace(
                w,
                role="spectator",
                members=(),
                limits=m.Limits(max_message_bytes=4096, max_players=8),
            ),
            "an empty room, with limits lowered by server config",
        ),
        invalid(
            "welcome_role_unknown", {**base, "role": "admin"}, "BAD_FIELD", "no such role", "role"
        ),
        invalid(
            "welcome_member_not_map",
            {**base, "members": ["p-3"]},
            "BAD_FIELD",
            "a str",
            "members[0]",
        ),
        invalid(
            "welcome_member_bad_id",
            {**base, "members": [{"player": "p 3", "name": "Bea"}]},
            "BAD_FIELD",
            "a space in an id",
            "members[0].player",
        ),
        invalid(
            "welcome_limit_missing",
            {**base, "limits": {k: v for k, v in base["limits"].items() if k != "max_players"}},
            "BAD_FIELD",
            "limits without max_players",
            "limits.max_players",
        ),
        invalid(
            "welcome_limit_above_v1",
            {**base, "limits": {**base["limits"], "max_players": 33}},
            "OUT_OF_RANGE",
            "v1 caps max_players at 32",
            "limits.max_players",
        ),
        invalid(
            "welcome_nested_bin_key",
            {**base, "limits": {**base["limits"], b"x": 1}},
            "MALFORMED",
            "a bin key inside a nested map",
        ),
        invalid(
            "welcome_nested_too_deep",
            {**base, "limits": {**base["limits"], "x": [[[[[[[1]]]]]]]}},
            "MALFORMED",
            "an unknown field in a nested map, 9 deep",
        ),
        invalid(
            "welcome_lookahead_negative",
            {**base, "lookahead_frames": -1},
            "OUT_OF_RANGE",
            "-1",
            "lookahead_frames",
        ),
    ]


def presence_cases() -> list[dict[str, Any]]:
    base = {"type": "presence", "event": "join", "room": "arena-7", "player": "p-3", "name": "Bea"}
    return [
        *(
            valid(f"presence_{e}", m.Presence(e, "arena-7", "p-3", "Bea"), f"a player {e}")
            for e in m.PRESENCE_EVENTS
        ),
        invalid(
            "presence_event_unknown", {**base, "event": "spawn"}, "BAD_FIELD", "spawn", "event"
        ),
        invalid(
            "presence_missing_name",
            {k: v for k, v in base.items() if k != "name"},
            "BAD_FIELD",
            "no name",
            "name",
        ),
    ]


def small_cases() -> dict[str, list[dict[str, Any]]]:
    return {
        "kick": [
            valid("kick", m.Kick("p-3"), "remove a player"),
            valid("kick_reason", m.Kick("p-3", "abusive language"), "with a reason"),
            invalid("kick_missing_player", {"type": "kick"}, "BAD_FIELD", "no player", "player"),
            invalid(
                "kick_reason_too_long",
                {"type": "kick", "player": "p-3", "reason": "x" * 513},
                "OUT_OF_RANGE",
                "513 bytes",
                "reason",
            ),
        ],
        "ping": [
            valid("ping", m.Ping(1.5), "client time 1.5 s"),
            valid("ping_realistic", m.Ping(86399.987654321), "a float64 that float32 cannot hold"),
            valid(
                "ping_at_size_limit",
                m.Ping(1.5),
                "8192 bytes, exactly the default max_message_bytes, is fine",
                (_padded_ping(8192),),
            ),
            valid(
                "ping_nested_at_limit",
                m.Ping(1.5),
                "an unknown field nested to exactly the depth limit (8) is fine",
                (pack({"type": "ping", "t0": 1.5, "x": [[[[[[[1]]]]]]]}),),
            ),
            invalid("ping_missing_t0", {"type": "ping"}, "BAD_FIELD", "no t0", "t0"),
            invalid("ping_t0_string", {"type": "ping", "t0": "1.5"}, "BAD_FIELD", "a str", "t0"),
            invalid("ping_t0_negative", {"type": "ping", "t0": -1.0}, "OUT_OF_RANGE", "-1 s", "t0"),
        ],
        "pong": [
            valid("pong", m.Pong(1.5, 1000.25, 1000.5), "an NTP-style answer"),
            invalid(
                "pong_missing_t2",
                {"type": "pong", "t0": 1.5, "t1": 2.0},
                "BAD_FIELD",
                "no t2",
                "t2",
            ),
            invalid(
                "pong_t1_nan",
                {"type": "pong", "t0": 1.5, "t1": float("nan"), "t2": 2.0},
                "OUT_OF_RANGE",
                "NaN",
                "t1",
            ),
        ],
        "error": [
            valid(
                "error", m.Error("RATE_LIMITED", "frames above 120 Hz dropped", False), "non-fatal"
            ),
            valid(
                "error_with_ref",
                m.Error(
                    "NOT_NORMALISED",
                    "trackers[2] orientation has norm 1.5",
                    False,
                    "trackers[2]",
                    41,
                ),
                "with the field and the frame's seq",
            ),
            valid("error_fatal", m.Error("KICKED", "", True), "fatal, empty message"),
            valid(
                "error_future_code",
                m.Error("FUTURE_CODE", "from a newer server", True),
                "unknown codes decode",
            ),
            invalid(
                "error_code_lower_case",
                {"type": "error", "code": "kicked", "message": "", "fatal": True},
                "BAD_FIELD",
                "lower case",
                "code",
            ),
            invalid(
                "error_fatal_int",
                {"type": "error", "code": "KICKED", "message": "", "fatal": 1},
                "BAD_FIELD",
                "1, not true",
                "fatal",
            ),
            invalid(
                "error_missing_fatal",
                {"type": "error", "code": "KICKED", "message": ""},
                "BAD_FIELD",
                "no fatal",
                "fatal",
            ),
        ],
        "bye": [
            valid("bye", m.Bye(), "no reason"),
            valid("bye_reason", m.Bye("game over"), "with a reason"),
            invalid(
                "bye_reason_int", {"type": "bye", "reason": 3}, "BAD_FIELD", "an int", "reason"
            ),
        ],
    }
