"""What a v2 pose record describes (online.protocol.record_state): the smallest-three layout
as the spec reads it, the items and their quaternion arithmetic, the skeleton bytes."""

from __future__ import annotations

import numpy as np
import pytest

from posecast.errors import BadFieldError, ProtocolError
from posecast.online.protocol import record_state


def _unit(rng: np.random.Generator, shape: tuple[int, ...]) -> np.ndarray:
    q = rng.normal(size=(*shape, 4))
    return q / np.linalg.norm(q, axis=-1, keepdims=True)


def _pack_word_by_word(q: np.ndarray) -> bytes:
    """The smallest-three layout read off proto/README.md, one word at a time."""
    out = bytearray()
    for row in q:
        k = max(range(4), key=lambda c: (abs(row[c]), -c))  # the first largest
        sign = -1.0 if row[k] < 0 else 1.0
        word = k << 45
        for n, c in enumerate(c for c in range(4) if c != k):
            word |= (round(row[c] * sign * record_state.SMALLEST3_SCALE) & 0x7FFF) << (15 * n)
        out += word.to_bytes(6, "little")
    return bytes(out)


def test_smallest_three_packs_and_unpacks_as_the_spec_reads() -> None:
    rng = np.random.default_rng(3)
    q = _unit(rng, (500,))
    h = 0.5**0.5
    q = np.concatenate(
        [q, [[0.5, -0.5, 0.5, -0.5], [h, -h, 0, 0], [0, 0, 0, -1], [-1, 0, 0, 0]]]
    )  # ties: the first largest is dropped
    blob = record_state.smallest3_pack(q)
    assert blob == _pack_word_by_word(q)
    back = record_state.smallest3_unpack(blob)
    sign = np.where(np.sum(back * q, axis=1) < 0, -1.0, 1.0)[:, None]
    np.testing.assert_allclose(back * sign, q, atol=1e-4)
    for i in range(len(q)):  # each component as one word's fields give it
        word = int.from_bytes(blob[6 * i : 6 * i + 6], "little")
        fields = [(word >> 15 * n & 0x7FFF) for n in range(3)]
        comps = [(f - 0x8000 if f & 0x4000 else f) / record_state.SMALLEST3_SCALE for f in fields]
        assert [x for c, x in enumerate(back[i]) if c != word >> 45 & 3] == comps
    bad = bytearray(blob[:6])
    bad[5] |= 0x80
    with pytest.raises(BadFieldError, match="reserved bit"):
        record_state.smallest3_unpack(bytes(bad))


def test_rotation_vectors_and_quaternions_invert_each_other_the_shorter_way() -> None:
    rng = np.random.default_rng(4)
    q = _unit(rng, (200,))
    v = record_state.quat2rotvec(q)
    assert np.all(np.linalg.norm(v, axis=-1) <= np.pi + 1e-12)  # the shorter way round
    back = record_state.rotvec2quat(v)
    same = np.where(q[:, 3:4] < 0, -q, q)  # q and -q are one rotation
    np.testing.assert_allclose(back, same, atol=1e-12)
    np.testing.assert_array_equal(record_state.quat2rotvec(np.array([0.0, 0, 0, 1])), [0, 0, 0])
    np.testing.assert_array_equal(record_state.rotvec2quat(np.zeros(3)), [0, 0, 0, 1])
    quarter = record_state.rotvec2quat(np.array([0.0, np.pi / 2, 0.0]))
    np.testing.assert_allclose(quarter, [0.0, np.sqrt(0.5), 0.0, np.sqrt(0.5)], atol=1e-15)
    np.testing.assert_allclose(np.linalg.norm(record_state.normalise(q * 3.0), axis=-1), 1.0)


def test_items_are_the_pelvis_world_rotation_then_each_joints_local_one() -> None:
    rng = np.random.default_rng(5)
    world = _unit(rng, (19,))
    items = record_state.world2items(world)
    np.testing.assert_array_equal(items[0], world[0])
    back = record_state.items2world(items)
    same = np.where(np.sum(back * world, axis=-1, keepdims=True) < 0, -back, back)
    np.testing.assert_allclose(same, world, atol=1e-12)
    ident = np.tile([0.0, 0.0, 0.0, 1.0], (19, 1))
    np.testing.assert_allclose(record_state.items2world(ident), ident)  # all local identity
    turned = ident.copy()
    turned[0] = world[0]  # only the pelvis turns: every joint turns with it
    np.testing.assert_allclose(record_state.items2world(turned), np.tile(world[0], (19, 1)))


def test_a_skeleton_is_108_bytes_of_tenths_of_a_millimetre() -> None:
    offsets = record_state.skeleton_offsets(1.25)  # a user 1.25 x smaller than the reference
    assert offsets.shape == (18, 3)
    blob = record_state.skeleton2bytes(offsets)
    assert len(blob) == 108
    np.testing.assert_allclose(record_state.bytes2skeleton(blob), offsets, atol=0.5e-4)
    np.testing.assert_allclose(record_state.skeleton_offsets(1.0) / 1.25, offsets)
    one = np.zeros((18, 3))
    one[0, 1] = 0.1234
    assert record_state.skeleton2bytes(one)[:6] == np.array([0, 1234, 0], "<i2").tobytes()
    too_long = np.zeros((18, 3))
    too_long[4, 2] = 3.2768
    with pytest.raises(ProtocolError) as info:
        record_state.skeleton2bytes(too_long)
    assert (info.value.code, info.value.field) == ("OUT_OF_RANGE", "skeleton")
    with pytest.raises(ProtocolError):
        record_state.skeleton2bytes(np.zeros((19, 3)))
