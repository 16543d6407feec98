"""The codec without sockets: round trips, quantisation bounds, limits, robustness."""

from __future__ import annotations

import msgpack
import numpy as np
import pytest

from posecast.errors import ProtocolError
from posecast.online.protocol import (
    MESSAGE_TYPES,
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
    decode,
    encode,
    from_wire,
    quantize,
    to_wire,
)
from posecast.online.protocol.messages import (
    V1_TYPES,
    V2_TYPES,
)


def _unit(rng: np.random.Generator, n: int) -> np.ndarray:
    q = rng.normal(size=(n, 4))
    return q / np.linalg.norm(q, axis=1, keepdims=True)


def _samples(rng: np.random.Generator) -> list[Message]:
    """One or more messages of every type, with awkward but valid values."""
    pos, quat = rng.uniform(-3, 3, size=(4, 3)), _unit(rng, 4)
    return [
        Hello(1, "tok", "lobby", "Ada"),
        Hello(1, "t" * 4096, "r" * 64, "Zoë 🎮", "hmd3", 72.0, ("a", "b.c:d-e_f")),
        Welcome(
            1, "p-1", "s-1", "backend", "lobby", 5.5, 60.0, 10, (Member("p-2", "Bea"),), Limits()
        ),
        Calibrate(height_m=1.8),
        Calibrate(pos=pos, quat=quat),
        Frame(2**32 - 1, 1e9 + 0.1, pos, quat),
        Frame(0, 0.0, pos, quat, valid=0b1010),
        Pose("p-1", 5, 12.0, rng.uniform(-1, 1, size=(19, 3)) + 500.0),
        Pose("p-1", 5, 12.0, rng.uniform(-1, 1, size=(19, 3)), _unit(rng, 19)),
        Presence("stale", "lobby", "p-2", "Bea"),
        Selector("p-2", "anomaly"),
        Selector("p-2", "target", "RIGHT_HAND", (0.1, 1.2, 0.3), margin_m=0.05),
        Selector("p-2", "obstacle", "LEFT_FOOT", (0.0, 0.0, 1.0), radius_m=0.3),
        Kick("p-2", "bye now"),
        Ping(3.25),
        Pong(3.25, 100.0, 100.001),
        Error("BAD_FIELD", "seq: expected an integer", False, "seq", 17),
        Bye(),
        Bye("done"),
    ]


def _samples_v2(rng: np.random.Generator) -> list[Message]:
    """The messages v2 adds or changes (v1's others are the same in v2)."""
    bones = rng.integers(-3000, 3000, size=(18, 3)).astype("<i2").tobytes()
    return [
        Hello(2, "tok", "lobby", "Ada", pose_rate_hz=30.0),
        Hello(2, "tok", "lobby", "Ada", forecast_ms=67.0),
        Welcome(
            2,
            "p-1",
            "s-1",
            "player",
            "lobby",
            5.5,
            60.0,
            10,
            (Member("p-2", "Bea", 3, bones), Member("p-1", "Ada", 0, bones)),
            Limits(),
            20.0,
        ),
        Presence("join", "lobby", "p-2", "Bea", 3, bones),
        Presence("leave", "lobby", "p-2", "Bea"),
        Poses(7.5, bytes(range(256)) * 40),
        Skeleton("p-2", 300, bones),
        PoseRate(15.0),
        Forecast(67.0),
        Resync(),
    ]


@pytest.mark.parametrize("version", [1, 2])
def test_every_type_round_trips(rng: np.random.Generator, version: int) -> None:
    samples = _samples(rng) if version == 1 else _samples_v2(rng)
    types = {type(s) for s in samples}
    if version == 1:
        assert types == {t for t in MESSAGE_TYPES if t.TYPE in V1_TYPES}
    else:
        assert {t.TYPE for t in types} | {"frame", "ping"} >= V2_TYPES - V1_TYPES
    for msg in samples:
        data = encode(msg)
        back = decode(data, version=version)
        assert type(back) is type(msg)
        if not isinstance(msg, Frame | Calibrate):  # those renormalise and blank slots
            assert encode(back) == data, msg.TYPE
        if isinstance(msg, Frame | Calibrate) and msg.pos is not None:
            assert isinstance(back, Frame | Calibrate)
            assert back.pos is not None and back.quat is not None and msg.quat is not None
            mask = [bool(getattr(msg, "valid", 15) >> i & 1) for i in range(4)]
            np.testing.assert_allclose(back.pos[mask], msg.pos[mask], atol=1e-15)
            np.testing.assert_allclose(back.quat[mask], msg.quat[mask], atol=1e-15)
        elif not isinstance(msg, Pose | Frame | Calibrate):
            assert back == msg


def test_encode_writes_float64_even_for_ints() -> None:
    data = encode(Ping(3))  # type: ignore[arg-type]  # an int where a float belongs
    assert data == msgpack.packb({"type": "ping", "t0": 3.0}, use_bin_type=True)
    assert b"\xcb" in data


def test_untracked_slots_read_as_origin_and_identity(rng: np.random.Generator) -> None:
    wire = to_wire(Frame(1, 1.0, rng.normal(size=(4, 3)), _unit(rng, 4), valid=0b0101))
    wire["trackers"][1] = [float("nan")] * 7
    f = decode(msgpack.packb(wire))
    assert isinstance(f, Frame)
    np.testing.assert_array_equal(f.pos[[1, 3]], 0.0)
    np.testing.assert_array_equal(f.quat[[1, 3]], [[0, 0, 0, 1]] * 2)


@pytest.mark.parametrize(
    ("scale", "ok"),
    [(1 + 0.999e-3, True), (1 - 0.999e-3, True), (1 + 1.001e-3, False), (1 - 1.001e-3, False)],
)
def test_quaternion_tolerance(rng: np.random.Generator, scale: float, ok: bool) -> None:
    q = _unit(rng, 4)
    wire = to_wire(Frame(9, 1.0, np.zeros((4, 3)), q))
    wire["trackers"][2][3:] = (q[2] * scale).tolist()
    data = msgpack.packb(wire)
    if ok:
        f = decode(data)
        assert isinstance(f, Frame)
        np.testing.assert_allclose(np.linalg.norm(f.quat, axis=1), 1.0, atol=1e-15)
        np.testing.assert_allclose(f.quat, q, atol=1e-15)
    else:
        with pytest.raises(ProtocolError) as info:
            decode(data)
        assert (info.value.code, info.value.field, info.value.ref_seq) == (
            "NOT_NORMALISED",
            "trackers[2]",
            9,
        )


def test_position_quantisation_error_is_half_a_millimetre(rng: np.random.Generator) -> None:
    for _ in range(200):
        root = rng.uniform(-1000, 1000, size=3)
        positions = root + rng.uniform(-2.5, 2.5, size=(19, 3))
        positions[0] = root
        data = encode(Pose("p", 1, 0.0, positions))
        back = decode(data)
        assert isinstance(back, Pose)
        err = np.abs(back.positions - positions)
        assert err.max() <= 0.0005 + 1e-9
        assert np.linalg.norm(back.positions - positions, axis=1).max() <= 0.0005 * 3**0.5 + 1e-9
        assert back.positions[0].tolist() == root.tolist()  # the root is exact
        assert encode(back) == data


def test_rotation_quantisation_error_is_below_1e4_rad(rng: np.random.Generator) -> None:
    worst = 0.0
    for _ in range(200):
        q = _unit(rng, 19)
        back = quantize.snorm2quat(quantize.quat2snorm(q))
        dot = np.abs(np.einsum("ij,ij->i", back / np.linalg.norm(back, axis=1, keepdims=True), q))
        worst = max(worst, float((2 * np.arccos(np.clip(dot, -1, 1))).max()))
        assert np.abs(back - q).max() <= 0.5 / 32767 + 1e-12
        assert np.abs(np.linalg.norm(back, axis=1) - 1).max() <= 3.1e-5
        assert np.sign(back[np.abs(q) > 1e-3]).tolist() == np.sign(q[np.abs(q) > 1e-3]).tolist()
    assert worst < 1e-4


def test_pose_sizes() -> None:
    rest = np.zeros((19, 3))
    assert len(quantize.pos2mm(rest)[1]) == quantize.POS_BYTES == 108
    assert len(quantize.quat2snorm(np.tile([0, 0, 0, 1.0], (19, 1)))) == quantize.ROT_BYTES == 152
    assert len(encode(Pose("p-17", 9, 20.5, rest))) == 189
    assert len(encode(Pose("p-17", 9, 20.5, rest, np.tile([0, 0, 0, 1.0], (19, 1))))) == 347


def test_pose_encoder_refuses_what_int16_cannot_hold() -> None:
    far = np.zeros((19, 3))
    far[7, 0] = 32.768
    with pytest.raises(ProtocolError) as info:
        encode(Pose("p", 1, 0.0, far))
    assert (info.value.code, info.value.field) == ("OUT_OF_RANGE", "pos_mm")
    far[7, 0] = np.nan
    with pytest.raises(ProtocolError):
        encode(Pose("p", 1, 0.0, far))
    with pytest.raises(ProtocolError) as info:
        encode(Pose("p", 1, 0.0, np.zeros((19, 3)), np.full((19, 4), 2.0)))
    assert info.value.code == "NOT_NORMALISED"


def test_frame_errors_carry_the_seq() -> None:
    wire = to_wire(Frame(77, 1.0, np.zeros((4, 3)), np.tile([0, 0, 0, 1.0], (4, 1))))
    wire["trackers"][0][0] = float("inf")
    with pytest.raises(ProtocolError) as info:
        decode(msgpack.packb(wire))
    assert (info.value.code, info.value.field, info.value.ref_seq) == (
        "OUT_OF_RANGE",
        "trackers[0]",
        77,
    )


def test_lowered_limits_apply() -> None:
    hello = encode(Hello(1, "tok", "lobby", "Adalovelace"))
    tight = Limits(max_message_bytes=1024, max_name_bytes=8)
    with pytest.raises(ProtocolError) as info:
        decode(hello, limits=tight)
    assert (info.value.code, info.value.field) == ("OUT_OF_RANGE", "name")
    with pytest.raises(ProtocolError) as info:
        decode(hello, max_bytes=len(hello) - 1)
    assert info.value.code == "TOO_LARGE"
    assert decode(hello, max_bytes=len(hello)) == Hello(1, "tok", "lobby", "Adalovelace")
    with pytest.raises(ProtocolError):
        decode(encode(Hello(1, "t", "lobby", "A", rate_hz=90.0)), limits=Limits(max_rate_hz=60))


def test_from_wire_takes_unpacked_values() -> None:
    assert from_wire({"type": "ping", "t0": 2}) == Ping(2.0)
    with pytest.raises(ProtocolError) as info:
        from_wire(["ping"])
    assert info.value.code == "MALFORMED"


def test_garbage_only_ever_raises_protocol_errors(rng: np.random.Generator) -> None:
    """Random bytes and mutated valid messages: a message or a ProtocolError, nothing else."""
    seeds = [encode(msg) for msg in _samples(rng)]
    for i in range(3000):
        if i % 3 == 0:
            data = rng.integers(0, 256, size=int(rng.integers(0, 64)), dtype=np.uint8).tobytes()
        else:
            buf = bytearray(seeds[i % len(seeds)])
            for _ in range(int(rng.integers(1, 4))):
                buf[int(rng.integers(0, len(buf)))] = int(rng.integers(0, 256))
            data = bytes(buf[: int(rng.integers(1, len(buf) + 1))])
        try:
            decode(data)
        except ProtocolError as exc:
            assert exc.code in {
                "MALFORMED",
                "TOO_LARGE",
                "UNKNOWN_TYPE",
                "BAD_FIELD",
                "OUT_OF_RANGE",
                "NOT_NORMALISED",
                "VERSION_UNSUPPORTED",
            }


def test_tracker_set_hello_and_sites_frames_round_trip() -> None:
    from posecast.online.protocol.messages import Frame as FrameMsg
    from posecast.online.protocol.messages import Hello as HelloMsg
    from posecast.tracking.sites import TrackerSet

    text = "head,left_hand,right_hand,left_foot:imu,right_foot:imu"
    h = decode(encode(HelloMsg(1, "t", "lobby", "Ada", layout=TrackerSet.parse(text))))
    assert isinstance(h, HelloMsg) and str(h.layout) == text
    pos = np.zeros((5, 3))
    pos[3] = [0.5, -9.0, 2.0]  # an acceleration, m/s^2
    quat = np.tile([0.0, 0.0, 0.0, 1.0], (5, 1))
    f = decode(encode(FrameMsg(7, 1.0, pos, quat, 0b11011, sites=True)))
    assert isinstance(f, FrameMsg) and f.sites and f.valid == 0b11011 and f.pos.shape == (5, 3)
    assert f.pos[3].tolist() == [0.5, -9.0, 2.0]
    assert f.pos[2].tolist() == [0.0, 0.0, 0.0]  # an untracked row reads as the origin


@pytest.mark.parametrize(
    ("wire", "code", "field"),
    [
        ({"layout": "head,left_hand,right_hand,tail"}, "BAD_FIELD", "layout"),
        ({"layout": "head,head,left_hand,right_hand"}, "BAD_FIELD", "layout"),
        ({"layout": "left_hand,right_hand"}, "BAD_FIELD", "layout"),
        ({"layout": "sites"}, "BAD_FIELD", "layout"),
    ],
)
def test_bad_tracker_sets_are_bad_fields(wire: dict[str, object], code: str, field: str) -> None:
    msg = {"type": "hello", "version": 1, "token": "t", "room": "r", "name": "n", **wire}
    with pytest.raises(ProtocolError) as err:
        decode(msgpack.packb(msg))
    assert err.value.code == code and err.value.field == field


@pytest.mark.parametrize(
    ("frame", "code", "field"),
    [
        ({"sites": [[0, 1, 0, 0, 0, 0, 1]] * 11}, "BAD_FIELD", "sites"),
        ({"sites": []}, "BAD_FIELD", "sites"),
        ({"sites": [[0, 1, 0, 0, 0, 0, 1]] * 3, "valid": 8}, "OUT_OF_RANGE", "valid"),
        ({"sites": [[0, 1, 0, 0, 0, 0, 1]] * 3, "trackers": [[0] * 7] * 4}, "BAD_FIELD", "sites"),
        ({"sites": [[0, 1, 0, 0, 0, 0, 2]] * 3}, "NOT_NORMALISED", "sites[0]"),
        ({"sites": [[2000, 1, 0, 0, 0, 0, 1]] * 3}, "OUT_OF_RANGE", "sites[0]"),
    ],
)
def test_bad_sites_frames(frame: dict[str, object], code: str, field: str) -> None:
    with pytest.raises(ProtocolError) as err:
        decode(msgpack.packb({"type": "frame", "seq": 1, "t": 0.5, **frame}))
    assert err.value.code == code and err.value.field == field
