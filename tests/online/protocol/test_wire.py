"""Per message type, the wire map and the dataclass (online.protocol.wire): which types and
fields each version knows, encoders writing the spec's key order with absent optionals
left out, decoders ignoring unknown keys and checking what each version checks."""

from __future__ import annotations

from typing import Any

import pytest

from posecast.errors import ProtocolError
from posecast.online.protocol.messages import (
    DEFAULT_LIMITS,
    MESSAGE_TYPES,
    PROTOCOL_V2,
    PROTOCOL_VERSION,
    V1_TYPES,
    V2_TYPES,
    Bye,
    Error,
    Hello,
    Kick,
    Ping,
    PoseRate,
    Resync,
)
from posecast.online.protocol.wire import DECODERS, ENCODERS, FIELD_ORDER, FIELD_ORDER_V1, pose_map


def _decode(version: int, m: dict[str, Any]) -> Any:
    _, decode = DECODERS[version][m["type"]]
    return decode(m, DEFAULT_LIMITS, version)


def test_each_version_decodes_its_types_and_every_type_encodes() -> None:
    assert set(DECODERS[PROTOCOL_VERSION]) == V1_TYPES
    assert set(DECODERS[PROTOCOL_V2]) == V2_TYPES
    assert set(ENCODERS) == set(FIELD_ORDER) == {cls.TYPE for cls in MESSAGE_TYPES}
    for version, table in DECODERS.items():
        for name, (known, _) in table.items():
            assert "type" in known and known - {"type"} <= set(FIELD_ORDER[name]), (version, name)


def test_v1_never_learns_the_v2_fields() -> None:
    v1 = {name: known for name, (known, _) in DECODERS[PROTOCOL_VERSION].items()}
    v2 = {name: known for name, (known, _) in DECODERS[PROTOCOL_V2].items()}
    assert v2["hello"] - v1["hello"] == {"pose_rate_hz", "forecast_ms"}
    assert v2["welcome"] - v1["welcome"] == {"pose_rate_hz", "forecast_ms"}
    assert v2["presence"] - v1["presence"] == {"handle", "skeleton"}
    assert "pose" in v1 and "pose" not in v2
    assert {"poses", "skeleton", "resync", "forecast"} <= set(v2) and "forecast" not in v1
    assert FIELD_ORDER_V1["presence"] == ("event", "room", "player", "name")
    assert "pose_rate_hz" not in FIELD_ORDER_V1["hello"]
    assert "forecast_ms" not in FIELD_ORDER_V1["hello"]


@pytest.mark.parametrize(
    ("message", "keys"),
    [
        (Ping(1.5), ["type", "t0"]),
        (Bye(), ["type"]),
        (Bye("done"), ["type", "reason"]),
        (Kick("p1"), ["type", "player"]),
        (
            Error("BAD_FIELD", "m", False, ref_seq=4),
            ["type", "code", "message", "fatal", "ref_seq"],
        ),
        (
            Error("BAD_FIELD", "m", True, "seq", 4),
            ["type", "code", "message", "fatal", "field", "ref_seq"],
        ),
        (
            Hello(2, "tok", "lobby", "Ada", pose_rate_hz=30.0),
            ["type", "version", "token", "room", "name", "pose_rate_hz"],
        ),
        (PoseRate(15.0), ["type", "rate_hz"]),
        (Resync(), ["type"]),
    ],
)
def test_encoders_write_type_first_then_the_spec_order_without_absent_optionals(
    message: Any, keys: list[str]
) -> None:
    m = ENCODERS[message.TYPE](message)
    assert list(m) == keys
    order = ["type", *FIELD_ORDER[message.TYPE]]
    assert [order.index(k) for k in m] == sorted(order.index(k) for k in m)
    floats = [k for k in m if isinstance(getattr(message, k, None), float)]
    assert all(type(m[k]) is float for k in floats)


def test_numbers_encode_as_floats_and_pose_maps_keep_the_spec_order() -> None:
    assert type(ENCODERS["ping"](Ping(2))["t0"]) is float  # an int given: a float written
    d = pose_map("p", 3, 1.0, [0.0, 1.0, 0.0], b"\x00" * 108, None)
    assert list(d) == ["type", "player", "seq", "t", "root", "pos_mm"]
    assert list(pose_map("p", 3, 1.0, [0.0] * 3, b"", b"r")) == [*d, "rot"]


def test_decoders_ignore_unknown_keys_and_read_nil_as_absent() -> None:
    assert _decode(1, {"type": "ping", "t0": 1, "later": [1, 2]}) == Ping(1.0)
    assert _decode(1, {"type": "bye", "reason": None}) == Bye(None)
    hello = {"type": "hello", "version": 1, "token": "", "room": "lobby", "name": "Ada",
             "pose_rate_hz": 999}  # fmt: skip
    assert _decode(1, hello).pose_rate_hz is None  # unknown in v1: not even checked


@pytest.mark.parametrize(
    ("version", "m", "code", "field"),
    [
        (1, {"type": "hello", "version": 2, "token": "", "room": "r", "name": "n"},
         "VERSION_UNSUPPORTED", "version"),
        (2, {"type": "hello", "version": 1, "token": "", "room": "r", "name": "n"},
         "VERSION_UNSUPPORTED", "version"),
        (1, {"type": "hello", "version": "1", "token": "", "room": "r", "name": "n"},
         "BAD_FIELD", "version"),
        (2, {"type": "hello", "version": 2, "token": "", "room": "r", "name": "n",
             "pose_rate_hz": 45}, "OUT_OF_RANGE", "pose_rate_hz"),
        (2, {"type": "pose_rate", "rate_hz": 25}, "OUT_OF_RANGE", "rate_hz"),
        (2, {"type": "poses", "t": 1.0, "data": "x"}, "BAD_FIELD", "data"),
        (1, {"type": "hello", "version": 1, "token": "", "room": "r", "name": "n",
             "layout": "tail"}, "BAD_FIELD", "layout"),
    ],
)  # fmt: skip
def test_decoders_refuse_with_the_specs_code_and_field(
    version: int, m: dict[str, Any], code: str, field: str
) -> None:
    with pytest.raises(ProtocolError) as info:
        _decode(version, m)
    assert (info.value.code, info.value.field) == (code, field)


def test_a_v2_pose_rate_is_one_of_the_ticks_divisors() -> None:
    for rate in (60, 30, 20, 15):
        assert _decode(2, {"type": "pose_rate", "rate_hz": rate}) == PoseRate(float(rate))
