"""Round trips and the codec's behaviour beyond the shared vectors."""

from __future__ import annotations

import msgpack
import numpy as np
import pytest

from posecast_client.codec import decode, encode, to_wire
from posecast_client.errors import (
    BadFieldError,
    NotNormalisedError,
    OutOfRangeError,
    ProtocolError,
    TooLargeError,
)
from posecast_client.protocol import (
    Bye,
    Calibrate,
    Error,
    Frame,
    Hello,
    Kick,
    Limits,
    Member,
    Ping,
    Pong,
    Pose,
    Presence,
    Selector,
    Welcome,
    seq_delta,
    seq_next,
)
from posecast_client.rotations import quat_normalize
from posecast_client.skeleton import reference_offsets


def _unit_quats(rng: np.random.Generator, n: int) -> np.ndarray:
    return quat_normalize(rng.normal(size=(n, 4)))


def test_simple_messages_round_trip() -> None:
    welcome = Welcome(1, "p-1", "s-1", "player", "r", 3.0, 60.0, 10,
                      (Member("p-1", "Ann"),), Limits(max_players=8))  # fmt: skip
    for msg in (
        Hello("tok", "room-1", "Ann", "hmd3", 90.0, ()),
        Hello("", "r", "Ann", watch=("a", "b")),
        welcome,
        Calibrate(height_m=1.8),
        Presence("join", "r", "p-1", "Ann"),
        Selector("p-1", "target", "LEFT_HAND", (0.1, 1.0, 0.3), margin_m=0.05),
        Kick("p-1", "bye now"),
        Ping(1.5),
        Pong(1.5, 2.0, 2.25),
        Error("BAD_FIELD", "x", False, "trackers[1]", 7),
        Bye(),
    ):
        data = encode(msg)
        assert to_wire(decode(data)) == to_wire(msg)  # messages with arrays compare by id
        assert encode(decode(data)) == data


def test_frames_round_trip_with_renormalised_quaternions(rng: np.random.Generator) -> None:
    for _ in range(50):
        pos = rng.uniform(-5, 5, (4, 3))
        quat = _unit_quats(rng, 4)
        valid = int(rng.integers(0, 16))
        out = decode(encode(Frame(int(rng.integers(0, 2**32)), 12.5, pos, quat, valid)))
        assert isinstance(out, Frame) and out.valid == valid
        for i in range(4):
            if valid >> i & 1:
                np.testing.assert_allclose(out.positions[i], pos[i])
                np.testing.assert_allclose(out.orientations[i], quat[i], atol=1e-15)
            else:  # untracked slots read as the origin with the identity rotation
                assert out.positions[i].tolist() == [0.0, 0.0, 0.0]
                assert out.orientations[i].tolist() == [0.0, 0.0, 0.0, 1.0]


def test_pose_quantisation_error_is_within_the_spec(rng: np.random.Generator) -> None:
    positions = rng.uniform(-1, 1, (19, 3)) + np.array([100.0, 0.0, -300.0])
    rotations = _unit_quats(rng, 19)
    out = decode(encode(Pose("p-1", 9, 20.5, positions, rotations)))
    assert isinstance(out, Pose) and out.rotations is not None
    assert out.positions[0].tolist() == positions[0].tolist()  # the root is exact
    assert np.abs(out.positions - positions).max() <= 0.0005 + 1e-9  # 0.5 mm per axis
    assert np.abs(out.rotations - rotations).max() <= 0.5 / 32767 + 1e-12
    assert len(encode(Pose("p-17", 9, 20.5, positions))) == 189  # the spec's size example


def test_pose_encoder_refuses_what_int16_cannot_hold() -> None:
    positions = np.zeros((19, 3))
    positions[5, 0] = 40.0  # 40 m from the pelvis
    with pytest.raises(OutOfRangeError):
        encode(Pose("p", 1, 1.0, positions))
    with pytest.raises(NotNormalisedError):
        encode(Pose("p", 1, 1.0, np.zeros((19, 3)), np.full((19, 4), 2.0)))


def test_a_frame_error_after_seq_carries_ref_seq() -> None:
    wire = to_wire(Frame(41, 1.0, np.zeros((4, 3)), np.tile([0, 0, 0, 1.0], (4, 1))))
    wire["trackers"][2][6] = 3.0  # |q| = 3
    with pytest.raises(NotNormalisedError) as info:
        decode(msgpack.packb(wire))
    assert (info.value.field, info.value.ref_seq) == ("trackers[2]", 41)


def test_lowered_limits_apply() -> None:
    data = encode(Hello("t", "room", "a" * 20))
    assert isinstance(decode(data), Hello)
    with pytest.raises(OutOfRangeError):
        decode(data, limits=Limits(max_name_bytes=16))
    with pytest.raises(TooLargeError):
        decode(data, max_bytes=10)


def test_pose_offsets_decode_from_the_root() -> None:
    pos = reference_offsets().cumsum(axis=0) + np.array([0.0, 1.0, 0.0])
    out = decode(encode(Pose("p", 1, 1.0, pos)))
    assert isinstance(out, Pose) and out.rotations is None
    np.testing.assert_allclose(out.positions, pos, atol=5e-4)


def test_garbage_only_ever_raises_protocol_errors(rng: np.random.Generator) -> None:
    good = encode(Frame(3, 1.0, np.zeros((4, 3)), np.tile([0, 0, 0, 1.0], (4, 1))))
    for _ in range(2000):
        data = bytearray(good)
        for _ in range(int(rng.integers(1, 4))):  # flip a few bytes
            data[int(rng.integers(0, len(data)))] = int(rng.integers(0, 256))
        try:
            decode(bytes(data))
        except ProtocolError as exc:
            assert exc.code in {"MALFORMED", "TOO_LARGE", "BAD_FIELD", "OUT_OF_RANGE",
                                "NOT_NORMALISED", "UNKNOWN_TYPE"}  # fmt: skip
    with pytest.raises(BadFieldError):
        decode(msgpack.packb({"type": "ping", "t0": True}))  # a bool is not a number


def test_seq_arithmetic_wraps() -> None:
    assert seq_next(2**32 - 1) == 0
    assert seq_delta(0, 2**32 - 1) == 1
    assert seq_delta(5, 5) == 0
    assert seq_delta(4, 5) == -1
    assert seq_delta(2**31 + 5, 5) == -(2**31)
