"""Per message type (``wire.py``): a decoder and an encoder for every type of the
spec, whose wire values are the type's fields; messages round-trip; a frame's own
rules (``ref_seq`` once its ``seq`` is read)."""

from __future__ import annotations

import msgpack
import numpy as np
import pytest

from posecast_client.codec import FIELDS, decode, encode, to_wire
from posecast_client.errors import (
    NotNormalisedError,
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
)
from posecast_client.wire import DECODERS, ENCODERS


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


def test_every_type_has_a_decoder_and_an_encoder_of_its_fields() -> None:
    """``to_wire`` keeps only the spec's fields, in their order: an encoder that wrote
    a misspelt key would lose the value without a word. So each encoder's keys must
    be the type's fields, and every type must have both directions."""
    assert set(DECODERS) == set(ENCODERS) == set(FIELDS)
    messages = [
        Hello("tok", "room-1", "Ann", "hmd3", 90.0, ("a",), 30.0, 50.0),
        Welcome(2, "p-1", "s-1", "player", "r", 3.0, 60.0, 10,
                (Member("p-1", "Ann", 7, bytes(108)),), Limits(), 60.0, 0.0),
        Calibrate(height_m=1.8),
        Frame(1, 1.0, np.zeros((4, 3)), np.tile([0, 0, 0, 1.0], (4, 1)), 0b0111),
        Pose("p-1", 9, 20.5, np.zeros((19, 3)), np.tile([0, 0, 0, 1.0], (19, 1))),
        Presence("join", "r", "p-1", "Ann", 7, bytes(108)),
        Selector("p-1", "obstacle", "LEFT_HAND", (0.1, 1.0, 0.3), radius_m=0.2),
        Kick("p-1", "bye now"),
        Ping(1.5),
        Pong(1.5, 2.0, 2.25),
        Error("BAD_FIELD", "x", False, "trackers[1]", 7),
        Bye("done"),
    ]  # fmt: skip
    for msg in messages:
        values = ENCODERS[msg.TYPE](msg)
        assert set(values) <= set(FIELDS[msg.TYPE]), msg.TYPE


def test_a_frame_error_after_seq_carries_ref_seq() -> None:
    wire = to_wire(Frame(41, 1.0, np.zeros((4, 3)), np.tile([0, 0, 0, 1.0], (4, 1))))
    wire["trackers"][2][6] = 3.0  # |q| = 3
    with pytest.raises(NotNormalisedError) as info:
        decode(msgpack.packb(wire))
    assert (info.value.field, info.value.ref_seq) == ("trackers[2]", 41)
