"""The bus wire format (posecast.online.cluster.bus): messages round trip, unknown
versions and kinds are skipped."""

from __future__ import annotations

import numpy as np

from posecast.online.cluster.bus import BUS_VERSION, BusMessage, decode_message, encode_message
from posecast.testing.poses import REST, pose_out


def test_bus_messages_round_trip_and_unknown_ones_are_skipped() -> None:
    for m in (
        BusMessage("tick", "n1"),
        BusMessage("join", "n1", "a", "Ann"),
        BusMessage("leave", "n2", "a"),
    ):
        assert decode_message(encode_message(m)) == m
    newer = encode_message(BusMessage("join", "n1", "a", "A")).replace(b"\xa1v\x02", b"\xa1v\x03")
    assert decode_message(newer) is None  # a newer node's message: skipped, not fatal
    assert decode_message(b"\xc1garbage") is None


def test_a_tick_carries_each_pose_quantised_with_its_scale() -> None:
    """A pose crosses as its quantised row: the receiving node makes the same v1 bytes
    the sender would have, and its v2 state (scale exact, rotations within snorm16)
    without decoding a wire message."""
    rot = np.tile([0.0, 0.0, np.sin(0.3), np.cos(0.3)], (19, 1))
    sent = (pose_out("a", 7, 12.5, REST + 1.0, rot, scale=1.25, reach_limited=True),
            pose_out("b", 8, 12.5))  # fmt: skip
    m = decode_message(encode_message(BusMessage("tick", "n1", poses=sent, events=(b"ev",))))
    assert m is not None and m.events == (b"ev",) and len(m.poses) == 2
    for got, want in zip(m.poses, sent, strict=True):
        assert got.v1() == want.v1()
        assert got.bus_row() == want.bus_row()
        assert got.state.scale == want.state.scale and got.state.root == want.state.root
        assert got.state.reach_limited == want.state.reach_limited
        assert np.abs(got.state.world - want.state.world).max() < 1e-4
        assert np.abs(got.state.items - want.state.items).max() < 2e-4


def test_a_malformed_bus_message_is_skipped_not_raised_nor_allocated() -> None:
    """What another node (or anything that can publish on the bus) sends is checked:
    an infinite burn expiry once raised OverflowError out of the listener, a pose
    given as an integer made ``bytes(n)`` allocate n zero bytes, and an event that was
    not bytes went into client outboxes as it was."""
    import msgpack

    def pack(body: dict[str, object]) -> bytes:
        out: bytes = msgpack.packb({"v": BUS_VERSION, "n": "other", **body}, use_bin_type=True)
        return out

    for body in (
        {"k": "burn", "p": "jti", "x": float("inf")},
        {"k": "burn", "p": "jti", "x": 1.5},
        {"k": "tick", "p": [["a", 200_000_000]]},
        {"k": "tick", "p": [["a", "text"]]},
        {"k": "tick", "p": [], "e": ["text"]},
        {"k": "tick", "p": [], "e": [7]},
        {"k": "tick", "p": [], "e": "not a list"},
        {"k": "tick", "p": [["a"]]},
        *({"k": "tick", "p": [row]} for row in _bad_rows()),
    ):
        assert decode_message(pack(body)) is None, body
    row = pose_out("a").bus_row()
    ok = decode_message(pack({"k": "tick", "p": [row], "e": [b"\x80"]}))
    assert ok is not None and ok.poses[0].bus_row() == row and ok.events == (b"\x80",)


def _bad_rows() -> list[object]:
    """A good row with one field wrong at a time."""
    good = pose_out("a").bus_row()
    wrong: list[tuple[int, object]] = [
        (0, 7), (1, 1.5), (1, "1"), (2, 1), (3, [0.0, 0.0]), (3, [0.0, 0.0, float("nan")]),
        (4, b"\x00" * 107), (5, b"\x00" * 152), (5, b"\x7f" * 152), (6, [0, 0, 10**9]),
        (6, [0.0, 0, 0]), (7, 0.0), (7, float("inf")), (7, 1), (8, 1),
    ]  # fmt: skip
    rows: list[object] = [good[:-1], [*good, 0], "row"]
    for i, v in wrong:
        row = list(good)
        row[i] = v
        rows.append(row)
    return rows
