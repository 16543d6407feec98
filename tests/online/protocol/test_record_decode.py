"""The reference decoder of v2 pose records (online.protocol.record_decode): avatar ids
in minimal LEB128, a blob of keyframes and deltas read to the state the encoder says a
client holds, and every malformed record a BAD_FIELD on ``data``."""

from __future__ import annotations

import numpy as np
import pytest

from posecast.errors import ProtocolError
from posecast.online.protocol.record_decode import Record, decode_records, read_leb128, write_leb128
from posecast.online.protocol.record_state import FLAG_REACH_LIMITED, KEYFRAME_BYTES, Recon
from posecast.online.protocol.records import PoseState, encode_delta


def _bad(data: bytes, refs: dict[int, Recon | None], why: str) -> None:
    with pytest.raises(ProtocolError, match=why) as info:
        decode_records(data, refs)
    assert (info.value.code, info.value.field) == ("BAD_FIELD", "data")


@pytest.mark.parametrize(
    ("value", "encoded"),
    [(0, b"\x00"), (127, b"\x7f"), (128, b"\x80\x01"), (300, b"\xac\x02"),
     (2**32 - 1, b"\xff\xff\xff\xff\x0f")],
)  # fmt: skip
def test_leb128_as_the_spec_writes_it(value: int, encoded: bytes) -> None:
    assert write_leb128(value) == encoded
    assert read_leb128(b"\x09" + encoded + b"\x09", 1) == (value, 1 + len(encoded))


@pytest.mark.parametrize(
    ("data", "why"),
    [
        (b"\x80\x00", "not minimal"),  # 0 written in two bytes
        (b"\x80\x80\x80\x80\x10", "too large"),  # 2**32
        (b"\x80\x80\x80\x80\x80\x01", "longer than 5 bytes"),
        (b"\x80", "cut short"),
    ],
)
def test_an_avatar_id_must_be_minimal_short_and_whole(data: bytes, why: str) -> None:
    with pytest.raises(ProtocolError, match=why):
        read_leb128(data, 0)


def _state(seed: int, player: str = "a", reach_limited: bool = False) -> PoseState:
    rng = np.random.default_rng(seed)
    world = rng.normal(size=(1, 19, 4))
    pos = np.zeros((1, 19, 3))
    pos[0, 0] = [1.5, 0.9, -2.25]
    state = PoseState.batch([player], [7], 0.0, pos, world, [1.0], [reach_limited])[0]
    assert state is not None
    return state


def test_a_keyframe_then_a_delta_read_back_to_the_encoders_state() -> None:
    a, b = _state(0), _state(1, "b", reach_limited=True)
    body_a, recon_a = a.keyframe()
    body_b, _ = b.keyframe()
    assert len(body_a) == KEYFRAME_BYTES and body_b[0] & FLAG_REACH_LIMITED
    refs: dict[int, Recon | None] = {3: None, 200: None}
    got = decode_records(write_leb128(3) + body_a + write_leb128(200) + body_b, refs)
    assert [(r.avatar_id, r.keyframe, r.reach_limited) for r in got] == [
        (3, True, False), (200, True, True),
    ]  # fmt: skip
    assert isinstance(got[0], Record) and refs[3] is got[0].recon
    assert got[0].recon.seq == 7 and got[0].recon.root == (15000, 9000, -22500)
    np.testing.assert_array_equal(got[0].recon.items, recon_a.items)
    # a delta: the pose turned a little and moved 1 cm along x
    world = a.world + np.random.default_rng(2).normal(scale=0.01, size=a.world.shape)
    world /= np.linalg.norm(world, axis=-1, keepdims=True)
    delta = encode_delta(recon_a, 8, (15100, 9000, -22500), world)
    assert delta is not None
    body, claimed = delta
    (rec,) = decode_records(write_leb128(3) + body, refs)
    assert not rec.keyframe and rec.recon.seq == 8 and rec.recon.root == (15100, 9000, -22500)
    np.testing.assert_allclose(rec.recon.items, claimed.items, rtol=0, atol=1e-12)
    assert refs[3] is rec.recon


def test_malformed_records_are_bad_fields_on_data() -> None:
    body, recon = _state(0).keyframe()
    _bad(write_leb128(4) + body, {3: None}, "never announced")
    _bad(write_leb128(3), {3: None}, "cut short")
    _bad(write_leb128(3) + bytes([0x80]) + body[1:], {3: None}, "reserved flag bits")
    _bad(write_leb128(3) + body[:-1], {3: None}, "keyframe is cut short")
    _bad(write_leb128(3) + bytes([0x00, 0x01]), {3: None}, "without a keyframe")
    _bad(write_leb128(3) + bytes([0x00, 0x00]), {3: recon}, "seq step is missing or 0")
    _bad(write_leb128(3) + bytes([0x00, 0x01, 0xFF]), {3: recon}, "delta is cut short")
    far = bytearray(body)
    far[5:9] = (10_000_001).to_bytes(4, "little", signed=True)  # root x past 1000 m
    _bad(write_leb128(3) + bytes(far), {3: None}, "beyond \\+-1000 m")
