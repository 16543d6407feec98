"""The codec's own behaviour beyond the shared vectors (``codec.py``): the limits in
force, and garbage that only ever raises protocol errors. Per-type round trips are
``test_wire.py``'s, field checks ``test_fields.py``'s, pose bytes ``test_quantize.py``'s."""

from __future__ import annotations

import msgpack
import numpy as np
import pytest

from posecast_client.codec import decode, encode
from posecast_client.errors import (
    BadFieldError,
    OutOfRangeError,
    ProtocolError,
    TooLargeError,
)
from posecast_client.protocol import (
    Frame,
    Hello,
    Limits,
    seq_delta,
    seq_next,
)


def test_lowered_limits_apply() -> None:
    data = encode(Hello("t", "room", "a" * 20))
    assert isinstance(decode(data), Hello)
    with pytest.raises(OutOfRangeError):
        decode(data, limits=Limits(max_name_bytes=16))
    with pytest.raises(TooLargeError):
        decode(data, max_bytes=10)


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
